"""Ego-motion estimators and surround detectors from outside the project (plug-ins).

Wherever an estimator is named (`omnibench run --estimator`, `omnibench estimate
--estimator`, a suite's ``estimators:`` list, `make_estimator`), a plug-in is named

- ``package.module:ClassName``: the module is imported (it must be importable: installed,
  or on ``PYTHONPATH``), or
- by a name that an installed package registers in the entry-point group
  ``omnibench.estimators`` (``[project.entry-points."omnibench.estimators"]`` in its
  ``pyproject.toml``: ``my-lk = "my_package.estimator:LKEstimator"``).

The class follows the protocol of the shipped `EgoMotionEstimator`:

- ``ClassName(camera, mount, **settings)``: the camera model
  (`estimator.camera.models.CameraModel`), its mount (`estimator.camera.mount.CameraMount`)
  and keyword settings (``omnibench estimate --set KEY=VALUE``);
- ``step(image, t_s, can_speed_mps) -> EgoMotionRecord``: image (H, W, 3) uint8 RGB, time
  [s], the latest CAN speed [m/s] (None or NaN when missing); the record of the motion
  from the previous frame to this one (the first frame's: a prior).
  `EgoMotionRecord.from_rates` builds one from a forward speed and a yaw rate.

Surround detectors/trackers are named the same way (`omnibench run --detector`, a suite's
``detectors:`` list; entry-point group ``omnibench.detectors``) and follow the protocol of
`estimator.surround.plugin.PluginSurround`:

- ``ClassName(camera, mount, **settings)``;
- ``step(frame, t_s, image, x, dt_s, speed_mps, yaw_rate_rps) -> list of tracks``: the
  frame index, its time [s], the image (H, W, 3) uint8 RGB, the ego-motion estimate since
  the previous frame (the state x (9,) and dt [s]; the car-frame speed [m/s] and yaw rate
  [rad/s]); each track a mapping or an object with ``track_id``, ``x_m``, ``y_m`` (ego road
  frame) and optionally ``vx_mps``, ``vy_mps`` and the box ``box_x_m``, ``box_y_m``,
  ``box_yaw_rad``, ``box_length_m``, ``box_width_m``.

A wrong name, a module that does not import, a missing class, or a class without the
protocol's methods is a ValueError naming what is wrong, raised before anything renders.
"""

from __future__ import annotations

import importlib
import importlib.metadata
import inspect
from typing import Any

ESTIMATOR_GROUP = "omnibench.estimators"
DETECTOR_GROUP = "omnibench.detectors"


def is_plugin_name(name: str, group: str = ESTIMATOR_GROUP) -> bool:
    """True for ``module:Class`` specs and names registered in the entry-point group."""
    return ":" in name or name in registered(group)


def registered(group: str) -> dict[str, importlib.metadata.EntryPoint]:
    """Entry points of installed packages in ``group``, by name."""
    return {ep.name: ep for ep in importlib.metadata.entry_points(group=group)}


def load_class(spec: str, group: str = ESTIMATOR_GROUP) -> type:
    """The class a plug-in name stands for (module docstring); ValueError otherwise."""
    if ":" in spec:
        module, _, attr = spec.partition(":")
        if not module or not attr:
            raise ValueError(f"plug-in {spec!r}: write it as package.module:ClassName")
        try:
            obj: Any = importlib.import_module(module)
        except Exception as e:  # any error of the user's module, named
            raise ValueError(f"plug-in {spec!r}: module {module!r} does not import: {e}") from e
        for part in attr.split("."):
            if not hasattr(obj, part):
                raise ValueError(f"plug-in {spec!r}: module {module!r} has no {attr!r}")
            obj = getattr(obj, part)
    else:
        eps = registered(group)
        if spec not in eps:
            raise ValueError(f"plug-in {spec!r}: no entry point of that name in {group!r}")
        try:
            obj = eps[spec].load()
        except Exception as e:
            raise ValueError(f"plug-in {spec!r}: its entry point does not load: {e}") from e
    if not inspect.isclass(obj):
        raise ValueError(f"plug-in {spec!r}: {obj!r} is not a class")
    return obj


def _accepts(fn: Any, n_positional: int) -> bool:
    """Whether ``fn`` (a function, or a class's __init__ unbound) accepts that many
    positional arguments after self."""
    try:
        sig = inspect.signature(fn)
    except (TypeError, ValueError):
        return True  # a builtin: cannot tell, let the call decide
    try:
        sig.bind(*([None] * (n_positional + 1)))
    except TypeError:
        return False
    return True


ESTIMATOR_STEP = ("image", "t_s", "can_speed_mps")
DETECTOR_STEP = ("frame", "t_s", "image", "x", "dt_s", "speed_mps", "yaw_rate_rps")


def check_estimator_class(cls: type, spec: str) -> type:
    """``cls`` if it follows the estimator protocol (module docstring); ValueError naming
    the missing or wrong part otherwise."""
    return _check_class(cls, spec, ESTIMATOR_STEP)


def check_detector_class(cls: type, spec: str) -> type:
    """``cls`` if it follows the surround detector protocol (module docstring)."""
    return _check_class(cls, spec, DETECTOR_STEP)


def _check_class(cls: type, spec: str, step_args: tuple[str, ...]) -> type:
    if not _accepts(cls.__init__, 2):
        raise ValueError(
            f"plug-in {spec!r}: {cls.__name__}(camera, mount, **settings) is not accepted "
            f"by its __init__{inspect.signature(cls.__init__)}"
        )
    args = ", ".join(step_args)
    step = getattr(cls, "step", None)
    if not callable(step):
        raise ValueError(f"plug-in {spec!r}: {cls.__name__} has no method step({args})")
    if not _accepts(step, len(step_args)):
        raise ValueError(
            f"plug-in {spec!r}: {cls.__name__}.step{inspect.signature(step)} does not accept "
            f"({args})"
        )
    return cls
