"""The config of the omni observation: what a highway-env config gives as ``observation``.

``{"type": "omnibench.OmniObservation", "camera": "omni-near", "width": 128, ...}``,
validated by :class:`OmniObservationConfig` (an unknown key is an error naming it).
Used by :mod:`sim.omni_observation`, :mod:`sim.env_renderer` and :mod:`sim.gym_env`.
"""

from __future__ import annotations

from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from sim.scenario import SensorConfig, VibrationConfig

__all__ = ["OBSERVATION_TYPE", "OBSERVATION_TYPES", "OmniObservationConfig"]

#: The name a highway-env config gives as ``observation.type``.
OBSERVATION_TYPE = "omnibench.OmniObservation"
#: Every name of the type: the bare class name is accepted too.
OBSERVATION_TYPES = (OBSERVATION_TYPE, "OmniObservation")


class OmniObservationConfig(BaseModel):
    """The ``observation`` config of the omni observation (unknown keys are errors).

    camera: preset name (``omni-near``, ``omni-far``, ``rectilinear-rear-left``), a
        camera file, or a ``resolve_camera`` mapping ``{preset: ..., ...}``.
    width, height: image size [px] (override the camera's; intrinsics rescale).
    vehicle_ids: also return the per-pixel vehicle-id image (Dict observation).
    face_px: cube-face size [px] (default: ``sim.drive.default_face_px``).
    view_range_m: how far around the observer the world is built [m].
    tile_m: side of a world tile [m].
    world_seed: fixed seed of the static world (default: from the episode seed).
    sensor: ``SensorConfig`` keys; every effect is off unless given.
    shadows: the vehicles cast shadows on the road (`sim.shadows`).
    vibration: ``VibrationConfig`` keys (amplitude_deg, frequency_hz); None = none.
        A tilted camera can be very slow on llvmpipe: its anisotropic texture
        filtering (sim/gl.py) took 5-30 s per frame at some poses with tilts of
        0.3-15 deg (Mesa 22.3), against ~0.1 s level.
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    type: str = OBSERVATION_TYPE
    camera: str | dict[str, Any] = "omni-near"
    width: int | None = Field(None, ge=8, le=4096)  # [px]
    height: int | None = Field(None, ge=8, le=4096)  # [px]
    vehicle_ids: bool = False
    face_px: int | None = Field(None, ge=16, le=4096)  # [px]
    view_range_m: float = Field(120.0, gt=5.0, le=2000.0)  # [m]
    tile_m: float = Field(60.0, ge=10.0, le=1000.0)  # [m]
    world_seed: int | None = Field(None, ge=0)
    sensor: SensorConfig = SensorConfig.exact()
    shadows: bool = False
    vibration: VibrationConfig | None = None

    @field_validator("type")
    @classmethod
    def _type(cls, v: str) -> str:
        if v not in OBSERVATION_TYPES:
            raise ValueError(f"must be one of {OBSERVATION_TYPES}, got {v!r}")
        return v

    @field_validator("sensor", mode="before")
    @classmethod
    def _sensor(cls, v: Any) -> Any:
        if v is None:
            return SensorConfig.exact()
        if isinstance(v, dict):  # effects not named stay off
            return {**SensorConfig.exact().model_dump(), **v}
        return v

    @classmethod
    def from_dict(
        cls, config: dict[str, Any], where: str = "omni observation"
    ) -> OmniObservationConfig:
        """Validate ``config``; a ValueError names ``where``, each bad key and its value."""
        try:
            return cls.model_validate(dict(config))
        except ValidationError as e:
            errs = "; ".join(
                f"{'.'.join(str(p) for p in err['loc']) or '(root)'}: {err['msg']}"
                f" (got {err.get('input')!r})"
                for err in e.errors()
            )
            raise ValueError(f"{where} config: {errs}") from None

    def camera_spec(self) -> str | dict[str, Any]:
        """The ``resolve_camera`` argument: the camera, resized when width/height are given."""
        if self.width is None and self.height is None:
            return self.camera
        spec = {"preset": self.camera} if isinstance(self.camera, str) else dict(self.camera)
        if self.width is not None:
            spec["width"] = int(self.width)
        if self.height is not None:
            spec["height"] = int(self.height)
        return spec

    def renderer_key(self) -> str:
        """What a shared renderer depends on (all but type and vehicle_ids)."""
        return self.model_dump_json(exclude={"type", "vehicle_ids"})
