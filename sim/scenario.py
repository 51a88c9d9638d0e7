"""The scenario schema: what a drive is, validated before anything renders.

A scenario names a highway-env environment and its config, the seed, the camera
(preset name or inline mapping), and the CAN, vibration and sensor models. Any
error names the file, the dotted key and the bad value; an unknown key is an
error. Scenario files and the shipped library are read by `scenarios.config`.
"""

from __future__ import annotations

import math
from typing import Any

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator


class ScenarioError(ValueError):
    """A scenario that cannot be used; the message names file, key and value."""


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class CanConfig(_Strict):
    """CAN-bus speed as the estimator receives it."""

    rate_hz: float = Field(50.0, gt=0)  # [Hz] message rate
    speed_bias: float = Field(0.0, gt=-0.9, lt=0.9)  # [-] relative scale error (0.08 = +8 %)
    speed_noise_mps: float = Field(0.0, ge=0)  # [m/s] white noise std
    quantization_mps: float = Field(0.01, ge=0)  # [m/s] resolution (0 = none)


class VibrationConfig(_Strict):
    """Roll/pitch oscillation of the camera relative to the car (the paper's A)."""

    amplitude_deg: float = Field(0.3, ge=0, le=5)  # [deg]
    frequency_hz: float = Field(2.0, gt=0)  # [Hz] roll; pitch runs at 1.37x


class SensorConfig(_Strict):
    """Camera sensor effects; every one can be turned off for exact tests."""

    noise_std: float = Field(2.0, ge=0)  # [DN] Gaussian pixel noise on 0..255
    motion_blur: bool = True  # blur by the true motion during the exposure
    exposure_s: float = Field(0.01, ge=0, le=0.2)  # [s] exposure time
    gain_drift: float = Field(0.03, ge=0, le=0.5)  # [-] std of slow exposure/gain changes
    vignetting: float = Field(0.25, ge=0, lt=1)  # [-] brightness loss at the image corner
    jpeg_quality: int | None = Field(90, ge=10, le=100)  # None = no compression

    @classmethod
    def exact(cls) -> SensorConfig:
        """All effects off: the rendered image as it is."""
        return cls(noise_std=0, motion_blur=False, gain_drift=0, vignetting=0, jpeg_quality=None)


class TrafficConfig(_Strict):
    """Vehicles added to the env's own traffic (`sim.traffic`): they enter where the road
    begins and drive to a random exit."""

    initial: int = Field(0, ge=0, le=200)  # [vehicles] spread over the entry roads at t = 0
    per_min: float = Field(0.0, ge=0, le=600)  # [vehicles/min] entering afterwards

    @property
    def active(self) -> bool:
        return self.initial > 0 or self.per_min > 0


class Scenario(_Strict):
    name: str = Field(min_length=1)
    description: str = ""
    env: str = "highway-v0"  # any registered highway-env id
    env_config: dict[str, Any] = Field(default_factory=dict)
    seed: int = 0
    duration_s: float = Field(10.0, gt=0, le=600)  # [s]
    fps: float = Field(15.0, gt=0, le=120)  # [Hz] camera frame rate
    ego_policy: str = "idm"  # "idm" (IDM + MOBIL lane changes) or "keep-lane"
    ego_speed_mps: float | None = Field(None, gt=0, le=60)  # [m/s] ego's IDM target; None: env's
    camera: str | dict[str, Any] = "omni-near"  # preset name or {preset: ..., overrides}
    view_range_m: float = Field(120.0, gt=5)  # [m] how far the scene is built
    detection_range_m: float = Field(25.0, gt=1)  # [m] range of the detection evaluation
    shadows: bool = False  # vehicles cast shadows on the road (`sim.shadows`; plane renderer)
    can: CanConfig = CanConfig()
    vibration: VibrationConfig = VibrationConfig()
    sensor: SensorConfig = SensorConfig()
    traffic: TrafficConfig = TrafficConfig()

    @field_validator("ego_policy")
    @classmethod
    def _policy(cls, v: str) -> str:
        if v not in ("idm", "keep-lane"):
            raise ValueError(f"must be 'idm' or 'keep-lane', got {v!r}")
        return v

    @property
    def n_frames(self) -> int:
        return int(math.floor(self.duration_s * self.fps + 1e-9))

    def to_dict(self) -> dict[str, Any]:
        """The scenario as plain data; an unset ego_speed_mps, no added traffic and no
        shadows are left out, so that renders and suite jobs of scenarios written before
        them keep their keys."""
        d = self.model_dump(mode="json")
        if d["ego_speed_mps"] is None:
            del d["ego_speed_mps"]
        if not self.shadows:
            del d["shadows"]
        if not self.traffic.active:
            del d["traffic"]
        return d


def format_errors(err: ValidationError, where: str) -> str:
    """One line per pydantic error: ``where``, the dotted key, the message and the value."""
    lines = []
    for e in err.errors():
        key = ".".join(str(p) for p in e["loc"]) or "<root>"
        msg = e["msg"].removeprefix("Value error, ")
        lines.append(f"{where}: key '{key}': {msg} (got {e.get('input')!r})")
    return "\n".join(lines)


def scenario_from_dict(data: Any, where: str = "<scenario>") -> Scenario:
    if not isinstance(data, dict):
        raise ScenarioError(f"{where}: a scenario must be a mapping, got {type(data).__name__}")
    try:
        sc = Scenario.model_validate(data)
    except ValidationError as e:
        raise ScenarioError(format_errors(e, where)) from None
    _check_env(sc.env, where)
    _check_camera(sc.camera, where)
    return sc


def _check_env(env_id: str, where: str) -> None:
    import gymnasium
    import highway_env  # noqa: F401  (registers the highway-env ids)

    if env_id not in gymnasium.registry:
        known = sorted(
            k
            for k in gymnasium.registry
            if "-v" in k and "highway" in str(gymnasium.registry[k].entry_point)
        )
        raise ScenarioError(f"{where}: key 'env': unknown environment {env_id!r}; known: {known}")


def _check_camera(spec: Any, where: str) -> None:
    from estimator.camera.files import resolve_camera

    try:
        resolve_camera(spec)
    except ValueError as e:
        raise ScenarioError(f"{where}: key 'camera': {e}") from None
