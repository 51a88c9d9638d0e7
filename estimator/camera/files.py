"""Camera files and presets: a camera model plus its mount, in YAML.

A camera file holds the model name, the model's constructor arguments and the
mount (`estimator.camera.mount.CameraMount`)::

    model: hyperbolic            # or pinhole
    a: 0.04                      # constructor arguments of HyperbolicCamera / PinholeCamera
    ...
    mount: {position_m: [0, 0, 1.95], yaw_deg: 0, pitch_deg: 0, roll_deg: 0, base: omni}
    # optional in mount: rear_axle_x_m: -2.5  (the car's no-slip point, car frame [m])
    # optional: vignetting: 0.25  (photometric calibration: the brightness lost at the
    # farthest corner, `estimator.camera.models.vignetting_gain`; rendered drives record theirs)

Constructor arguments left out take the constructor's defaults; ``mount`` may be
left out (``CameraMount`` defaults) and ``mount.base`` defaults to the model's
kind (``omni`` for hyperbolic, ``pinhole`` for pinhole). Presets live in
``estimator/camera/presets/<name>.yaml``: ``omni-near``, ``omni-far``,
``rectilinear-rear-left``.

`resolve_camera` also takes a mapping that starts from a preset (or a camera
file) and overrides constructor arguments by name, the mount's fields, and
``mount_height_m`` (the viewpoint's height above the road [m], replacing
``mount.position_m[2]``)::

    {preset: omni-far, a: 0.05, width: 800, height: 800, mount_height_m: 2.1}

When the image size (or, for the omni camera, the mirror a/b or the max
elevation) changes, the intrinsics that are *not* given are recomputed:

- hyperbolic: ``fu``, ``fv``, ``u0``, ``v0`` come from `HyperbolicCamera.from_fov`,
  so the max-elevation circle stays inside the image with the base camera's
  rim margin (scaled by the smaller of the width/height ratios), centred;
- pinhole: the image is resampled: ``fu *= sx``, ``skew *= sx``, ``fv *= sy``,
  ``u0 = (u0 + 0.5) sx - 0.5``, ``v0 = (v0 + 0.5) sy - 0.5`` with
  ``sx = width'/width``, ``sy = height'/height`` (same field of view).

A car-body mask (``body_mask.png`` beside a drive's ``camera.yaml``; ``--body-mask`` for
a recording) is a grey PNG of the camera's size, nonzero where the camera sees the car's
own body (`load_body_mask`); surround analysis then sees the road up to the body's
silhouette instead of the body cone (`CameraModel.with_body_mask`).

Every problem (unknown key, wrong type, bad value, unknown preset, unreadable
YAML) raises `CameraFileError` (a ValueError) naming the file or spec, the
dotted key and the bad value. Types are strict: ``width: 640.5`` or
``a: "0.04"`` are errors.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, create_model

from estimator.camera.models import CAMERA_MODELS, CameraModel, HyperbolicCamera, PinholeCamera
from estimator.camera.mount import CameraMount

PRESETS_DIR = Path(__file__).resolve().parent / "presets"

_KIND_OF_MODEL = {name: cls.kind for name, cls in CAMERA_MODELS.items()}


class CameraFileError(ValueError):
    """A camera file, preset or spec is missing or invalid."""


# --------------------------------------------------------------------- schema
_STRICT = ConfigDict(extra="forbid", strict=True)


class MountSpec(BaseModel):
    """``mount:`` section; fields of `CameraMount`."""

    model_config = _STRICT
    position_m: list[float] = Field(default=[0.0, 0.0, 1.95], min_length=3, max_length=3)  # [m]
    yaw_deg: float = 0.0  # [deg]
    pitch_deg: float = 0.0  # [deg]
    roll_deg: float = 0.0  # [deg]
    base: Literal["omni", "pinhole"] | None = None  # default: the model's kind
    rear_axle_x_m: float | None = None  # [m] car frame; None: unknown (no kinematic constraint)


class HyperbolicSpec(BaseModel):
    """A hyperbolic camera file (`HyperbolicCamera` arguments)."""

    model_config = _STRICT
    model: Literal["hyperbolic"]
    a: float  # [m]
    b: float  # [m]
    fu: float  # [px]
    fv: float  # [px]
    u0: float  # [px]
    v0: float  # [px]
    skew: float = 0.0  # [px]
    width: int = 640  # [px]
    height: int = 640  # [px]
    max_elevation_deg: float = 5.0  # [deg]
    body_mask_deg: float = 75.0  # [deg]
    vignetting: float = 0.0  # [-] brightness lost at the farthest corner (flat-field)
    mount: MountSpec | None = None


class PinholeSpec(BaseModel):
    """A pinhole camera file (`PinholeCamera` arguments)."""

    model_config = _STRICT
    model: Literal["pinhole"]
    fu: float  # [px]
    fv: float  # [px]
    u0: float  # [px]
    v0: float  # [px]
    skew: float = 0.0  # [px]
    width: int = 640  # [px]
    height: int = 480  # [px]
    vignetting: float = 0.0  # [-] brightness lost at the farthest corner (flat-field)
    mount: MountSpec | None = None


_SPECS: dict[str, type[BaseModel]] = {"hyperbolic": HyperbolicSpec, "pinhole": PinholeSpec}


class MountOverride(BaseModel):
    """Partial ``mount:`` in a `resolve_camera` mapping."""

    model_config = _STRICT
    position_m: list[float] | None = Field(default=None, min_length=3, max_length=3)
    yaw_deg: float | None = None
    pitch_deg: float | None = None
    roll_deg: float | None = None
    base: Literal["omni", "pinhole"] | None = None
    rear_axle_x_m: float | None = None


def _override_model(model: str) -> type[BaseModel]:
    """Schema of a `resolve_camera` mapping for a base camera of ``model``."""
    fields: dict[str, Any] = {
        name: (ann | None, None)
        for name, ann in (
            (n, f.annotation) for n, f in _SPECS[model].model_fields.items() if n != "mount"
        )
    }
    fields["model"] = (Literal[model] | None, None)  # type: ignore[valid-type]
    fields["mount"] = (MountOverride | None, None)
    fields["mount_height_m"] = (float | None, None)

    return create_model(f"{model.title()}Override", __config__=_STRICT, **fields)


_OVERRIDES = {m: _override_model(m) for m in _SPECS}


# -------------------------------------------------------------- error helpers
def _fields_at(schema: type[BaseModel], loc: tuple) -> list[str]:
    """Allowed keys of the (nested) model at ``loc`` (its parent path)."""
    model: Any = schema
    for part in loc:
        f = model.model_fields.get(part) if isinstance(part, str) else None
        if f is None:
            return []
        ann = f.annotation
        sub = [a for a in getattr(ann, "__args__", (ann,)) if isinstance(a, type)]
        sub = [a for a in sub if issubclass(a, BaseModel)]
        if not sub:
            return []
        model = sub[0]
    return list(model.model_fields)


def _format_validation(err: ValidationError, where: str, schema: type[BaseModel]) -> str:
    lines = []
    for e in err.errors():
        loc = tuple(e["loc"])
        key = ".".join(str(p) for p in loc) or "<top>"
        value = e.get("input")
        if e["type"] == "extra_forbidden":
            allowed = _fields_at(schema, loc[:-1])
            lines.append(
                f"unknown key '{key}' (value {value!r}); allowed keys: {', '.join(allowed)}"
            )
            continue
        if e["type"] == "missing":
            lines.append(f"missing key '{key}'")
            continue
        hint = ""
        if isinstance(value, str):
            try:
                float(value)
                hint = " (write a number, not text; YAML reads 1e-3 as text: write 1.0e-3)"
            except ValueError:
                pass
        lines.append(f"key '{key}': {e['msg']}, got {value!r}{hint}")
    return f"{where}: " + "; ".join(lines)


def preset_names() -> list[str]:
    """Names of the camera presets shipped in ``estimator/camera/presets``."""
    return sorted(p.stem for p in PRESETS_DIR.glob("*.yaml"))


# ------------------------------------------------------------- dict <-> objects
def camera_from_dict(data: Any, where: str = "camera spec") -> tuple[CameraModel, CameraMount]:
    """Validate a camera-file mapping and build ``(camera, mount)``.

    ``where`` names the source (file or spec) in error messages.
    """
    if not isinstance(data, Mapping):
        raise CameraFileError(f"{where}: expected a mapping of keys, got {type(data).__name__}")
    data = dict(data)
    model = data.get("model")
    if model is None:
        raise CameraFileError(f"{where}: missing key 'model' (one of {', '.join(_SPECS)})")
    if model not in _SPECS:
        raise CameraFileError(
            f"{where}: key 'model': unknown camera model {model!r}; known: {', '.join(_SPECS)}"
        )
    schema = _SPECS[model]
    try:
        spec = schema.model_validate(data)
    except ValidationError as e:
        raise CameraFileError(_format_validation(e, where, schema)) from None
    params = spec.model_dump(exclude_unset=True, exclude={"model", "mount"})
    try:
        camera = CAMERA_MODELS[model](**params)
    except ValueError as e:
        raise CameraFileError(f"{where}: {e}") from None
    mount_data = spec.mount.model_dump(exclude_unset=True) if spec.mount else {}
    mount = _make_mount(mount_data, camera, where)
    return camera, mount


def _make_mount(fields: dict[str, Any], camera: CameraModel, where: str) -> CameraMount:
    fields = dict(fields)
    base = fields.get("base") or camera.kind
    if base != camera.kind:
        raise CameraFileError(
            f"{where}: key 'mount.base': {base!r} does not match model {camera.model!r} "
            f"(expects {camera.kind!r})"
        )
    fields["base"] = base
    if "position_m" in fields:
        fields["position_m"] = tuple(float(x) for x in fields["position_m"])
    try:
        return CameraMount(**fields)
    except ValueError as e:
        raise CameraFileError(f"{where}: {e}") from None


def camera_to_dict(camera: CameraModel, mount: CameraMount) -> dict[str, Any]:
    """The camera-file mapping of ``(camera, mount)``."""
    if not isinstance(camera, CameraModel):
        raise TypeError(f"camera must be a CameraModel, got {type(camera).__name__}")
    if not isinstance(mount, CameraMount):
        raise TypeError(f"mount must be a CameraMount, got {type(mount).__name__}")
    if mount.base != camera.kind:
        raise ValueError(
            f"mount base {mount.base!r} does not match camera model {camera.model!r} "
            f"(expects {camera.kind!r})"
        )
    return {**camera.to_dict(), "mount": mount.to_dict()}


# --------------------------------------------------------------------- files
def _read_yaml(path: Path, where: str) -> Any:
    try:
        text = path.read_text()
    except OSError as e:
        raise CameraFileError(f"{where}: cannot read: {e.strerror or e}") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        at = f" at line {mark.line + 1}, column {mark.column + 1}" if mark else ""
        problem = getattr(e, "problem", None) or str(e)
        raise CameraFileError(f"{where}: invalid YAML{at}: {problem}") from None
    if data is None:
        raise CameraFileError(f"{where}: file is empty")
    return data


def _locate(path_or_name: str | os.PathLike) -> tuple[Path, str]:
    """(path, description) of a preset name or a camera file."""
    if isinstance(path_or_name, str) and path_or_name in preset_names():
        path = PRESETS_DIR / f"{path_or_name}.yaml"
        return path, f"camera preset '{path_or_name}' ({path})"
    if not isinstance(path_or_name, (str, os.PathLike)):
        raise CameraFileError(
            f"camera must be a preset name or a file path, got {type(path_or_name).__name__} "
            f"{path_or_name!r}"
        )
    path = Path(path_or_name)
    if path.is_file():
        return path, f"camera file '{path}'"
    known = ", ".join(preset_names())
    text = os.fspath(path_or_name)
    if isinstance(path_or_name, str) and os.sep not in text and not path.suffix:
        raise CameraFileError(f"unknown camera preset {text!r}; known presets: {known}")
    raise CameraFileError(f"camera file '{text}' not found (known presets: {known})")


def load_camera(path_or_name: str | os.PathLike) -> tuple[CameraModel, CameraMount]:
    """``(camera, mount)`` from a preset name (``omni-near``, ...) or a camera file path."""
    path, where = _locate(path_or_name)
    return camera_from_dict(_read_yaml(path, where), where)


BODY_MASK_FILE = "body_mask.png"  # a drive's car-body pixels, beside its camera.yaml


def load_body_mask(path: str | os.PathLike, camera: CameraModel) -> np.ndarray:
    """(height, width) bool: the pixels of ``camera`` that see the car's own body, from a
    grey (or RGB) PNG of the camera's size, nonzero there. `CameraFileError` naming the
    file when it is unreadable, of another size, or marks no pixel or every pixel."""
    path = Path(path)
    img = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise CameraFileError(f"{path}: cannot read the body mask (a PNG image)")
    body = (img if img.ndim == 2 else img.max(axis=2)) > 0
    if body.shape != (camera.height, camera.width):
        raise CameraFileError(
            f"{path}: body mask is {body.shape[1]}x{body.shape[0]} (WxH), the camera "
            f"{camera.width}x{camera.height}"
        )
    if not body.any() or body.all():
        raise CameraFileError(
            f"{path}: body mask marks {'no' if not body.any() else 'every'} pixel"
        )
    return body


def with_folder_body_mask(camera: CameraModel, folder: str | os.PathLike) -> CameraModel:
    """``camera`` with the car-body mask that a folder holds (``folder/body_mask.png``, as
    a rendered drive does; `CameraModel.with_body_mask`), else ``camera`` itself."""
    path = Path(folder) / BODY_MASK_FILE
    return camera.with_body_mask(load_body_mask(path, camera)) if path.exists() else camera


def save_camera(path: str | os.PathLike, camera: CameraModel, mount: CameraMount) -> Path:
    """Write a camera file atomically (temporary file in the same folder + os.replace)."""
    path = Path(path)
    text = "# omnibench camera file (estimator/camera/files.py; frames: docs/CONVENTIONS.md)\n"
    text += yaml.safe_dump(camera_to_dict(camera, mount), sort_keys=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise
    return path


# ------------------------------------------------------------------ resolving
def resolve_camera(
    spec: str | os.PathLike | Mapping[str, Any],
) -> tuple[CameraModel, CameraMount]:
    """``(camera, mount)`` from a preset name, a file path, or an override mapping.

    A mapping with ``preset`` (a preset name or a file path) starts from it and
    overrides the keys it gives (see the module docstring for the rescaling
    rules); a mapping without ``preset`` must be a complete camera description.
    """
    if isinstance(spec, (str, os.PathLike)):
        return load_camera(spec)
    if not isinstance(spec, Mapping):
        raise CameraFileError(
            f"camera spec must be a preset name, a file path or a mapping, "
            f"got {type(spec).__name__} {spec!r}"
        )
    spec = dict(spec)
    if "preset" not in spec:
        return camera_from_dict(spec, "camera spec")
    preset = spec.pop("preset")
    if not isinstance(preset, (str, os.PathLike)):
        raise CameraFileError(
            f"camera spec: key 'preset': expected a preset name or a file path, got {preset!r}"
        )
    base_cam, base_mount = load_camera(preset)
    where = f"camera spec (preset {os.fspath(preset)!r})"
    schema = _OVERRIDES[base_cam.model]
    try:
        over = schema.model_validate(spec)
    except ValidationError as e:
        raise CameraFileError(_format_validation(e, where, schema)) from None
    given = over.model_dump(exclude_unset=True)
    given.pop("model", None)
    mount_over = given.pop("mount", None) or {}
    height = given.pop("mount_height_m", None)

    params = base_cam.params()
    params.update({k: v for k, v in given.items() if v is not None})
    params.update(_rederived_intrinsics(base_cam, params, given, where))
    try:
        camera = type(base_cam)(**params)
    except ValueError as e:
        raise CameraFileError(f"{where}: {e}") from None

    mount_fields = base_mount.to_dict()
    mount_fields.update({k: v for k, v in mount_over.items() if v is not None})
    if height is not None:
        if mount_over.get("position_m") is not None:
            raise CameraFileError(
                f"{where}: give either 'mount_height_m' ({height!r}) or 'mount.position_m' "
                f"({mount_over['position_m']!r}), not both"
            )
        mount_fields["position_m"] = [*mount_fields["position_m"][:2], height]
    return camera, _make_mount(mount_fields, camera, where)


def _rederived_intrinsics(
    base: CameraModel, params: dict[str, Any], given: dict[str, Any], where: str
) -> dict[str, Any]:
    """fu, fv, u0, v0 (and pinhole skew) not in ``given``, recomputed after a geometry change."""
    sx = params["width"] / base.width
    sy = params["height"] / base.height
    free = [k for k in ("fu", "fv", "u0", "v0") if k not in given]
    if isinstance(base, PinholeCamera):
        if sx == 1.0 and sy == 1.0:
            return {}
        new = {
            "fu": base.fu * sx,
            "fv": base.fv * sy,
            "u0": (base.u0 + 0.5) * sx - 0.5,
            "v0": (base.v0 + 0.5) * sy - 0.5,
        }
        out = {k: new[k] for k in free}
        if "skew" not in given:
            out["skew"] = base.skew * sx
        return out
    assert isinstance(base, HyperbolicCamera)
    keys = ("width", "height", "a", "b", "max_elevation_deg")
    if all(params[k] == getattr(base, k) for k in keys):
        return {}
    margin = min(base.width, base.height) / 2.0 - min(base.fu, base.fv) * base.rim_radius(
        base.a, base.b, base.max_elevation_deg
    )
    try:
        fit = HyperbolicCamera.from_fov(
            params["a"],
            params["b"],
            params["width"],
            params["height"],
            params["max_elevation_deg"],
            rim_margin_px=margin * min(sx, sy),
            body_mask_deg=params["body_mask_deg"],
        )
    except ValueError as e:
        raise CameraFileError(f"{where}: {e}") from None
    return {k: getattr(fit, k) for k in free}
