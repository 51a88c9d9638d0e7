"""Suite files: scenarios x cameras x estimators x seeds x overrides, as jobs.

A suite file (YAML, validated; an unknown key is an error naming file, key and
value)::

    name: paper                       # default: the file's stem
    description: "..."
    role: tuning                      # tuning | check | regression | training (docs/SUITES.md)
    scenarios: [highway-omni-near, intersection-*, ../my/drive.yaml]
    cameras: [omni-near, {preset: omni-far, width: 480, height: 480}]
    estimators: [direct, can-only]    # default [direct]
    seeds: [7, 8]                     # default: each scenario's own seed
    overrides:                        # dotted scenario keys; a list is a sweep
      can.speed_bias: [-0.15, 0.0, 0.15]
      sensor.noise_std: 1.0           # a single value: applied to every job
    frames: 30                        # only the first N frames of every drive
    video: true                       # analysis.mp4 per job
    thresholds:                       # per suite; a job missing one fails (junit.xml)
      detection.recall: {min: 0.3}
      ego.speed_rmse_pct: {max: 5.0, estimators: [direct]}

Scenario entries are shipped names, paths (relative to the suite file, then to
the working directory) or globs: a glob with a ``/`` or a ``.yaml`` suffix
matches files, any other glob matches shipped names (``highway-*``).

An override value that is a list is a sweep (one job per value; several swept
keys give their product); to set a list-valued key write ``[[1, 2]]``.
``camera`` and ``seed`` are not overrides: use ``cameras`` and ``seeds``.

Every combination is a `Job` with a stable id: a hash of the resolved scenario
(after camera, seed and overrides), the estimator and the effective frame count.
Its render is shared with every job that differs only in the estimator: the
render key hashes the resolved scenario, the frame count, the resolved camera
(intrinsics and mount) and `code_version()` (the sources that shape a render).
"""

from __future__ import annotations

import copy
import fnmatch
import functools
import hashlib
import itertools
import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from estimator.surround.detection import DEFAULT_DETECTOR
from scenarios.config import (
    LIBRARY_DIR,
    Scenario,
    ScenarioError,
    known_scenarios,
    resolve_scenario_path,
    scenario_from_dict,
)
from sim.scenario import format_errors

SUITES_DIR = Path(__file__).parent / "suites"
REPO_DIR = Path(__file__).resolve().parents[1]

# Sources whose change changes a render (the render cache key): all of sim/ and the
# camera package (models, files, mount, presets), geometry and synthetic road of estimator/.
RENDER_SOURCES = (
    "sim/**/*",
    "estimator/camera/**/*",
    "estimator/geometry.py",
    "estimator/synthetic.py",
)

# Flattened metric keys of metrics.json (scenarios.runner) that thresholds may name.
KNOWN_METRICS = (
    "frames",
    "ego.speed_rmse_mps",
    "ego.speed_rmse_pct",
    "ego.yaw_rate_rmse_dps",
    "ego.yaw_rate_rmse_exposure_dps",
    "ego.angle_rmse_deg",
    "ego.prior_speed_rmse_mps",
    "ego.prior_yaw_rate_rmse_dps",
    "ego.prior_angle_rmse_deg",
    "ego.roll_rmse_deg",
    "ego.pitch_rmse_deg",
    "ego.angle_yaw_rmse_deg",
    "ego.speed_nees",
    "ego.yaw_rate_nees",
    "ego.angle_nees",
    "ego.mean_speed_mps",
    "ego.frames_compared",
    "ego.frames_nonfinite",
    "detection.recall",
    "detection.precision",
    "detection.gt_count",
    "detection.matched",
    "tracking.mota",
    "tracking.idf1",
    "tracking.hota",
    "tracking.id_switches",
    "tracking.hota_box",
    "localization.median_error_m",
    "localization.p90_error_m",
    "localization.centre_median_error_m",
    "compensation.ratio",
    "compensation.road_rms",
    "compensation.road_rms_gt",
    "point_pull.speed_pull_pct",
    "point_pull.yaw_rate_pull_dps",
    "timing.render_ms_per_frame",
    "timing.estimate_ms_per_frame",
    "timing.detect_track_ms_per_frame",
)


# what a suite's role says of its figures (docs/SUITES.md); shown in reports and RESULTS.md
ROLE_MEANING = {
    "tuning": "tuning suite: settings were chosen on these drives, so its figures are not held out",
    "check": "check suite: rendered and measured only after the settings were chosen",
    "regression": "regression suite: its figures guard against changes; they are not held out",
    "training": "training suite: a fitted model learned from it; its figures are not held out",
}


class SuiteError(ValueError):
    """A suite file that cannot be used; the message names file, key and value."""


# ----------------------------------------------------------------- the schema
class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class Threshold(_Strict):
    """Bounds on one metric; ``estimators`` limits it to those estimators (default all)."""

    min: float | None = None
    max: float | None = None
    estimators: list[str] | None = None

    def applies_to(self, estimator: str) -> bool:
        return self.estimators is None or estimator in self.estimators


class SuiteSpec(_Strict):
    name: str = Field(min_length=1, pattern=r"^[A-Za-z0-9._-]+$")
    description: str = ""
    role: Literal["tuning", "check", "regression", "training"] | None = None  # keys of ROLE_MEANING
    scenarios: list[str] = Field(min_length=1)
    cameras: list[str | dict[str, Any]] | None = Field(None, min_length=1)
    estimators: list[str] = Field(default_factory=lambda: ["direct"], min_length=1)
    # surround detectors (`estimator.surround.detection.DETECTOR_METHODS`): "hypotheses"
    # (the default), "learned" (a fitted pixel classifier) and "paper" (section 5 as
    # written, a baseline)
    detectors: list[str] = Field(default_factory=lambda: [DEFAULT_DETECTOR], min_length=1)
    seeds: list[int] | None = Field(None, min_length=1)
    overrides: dict[str, Any] = Field(default_factory=dict)
    frames: int | None = Field(None, ge=2)  # only the first N frames of each drive
    video: bool = True  # analysis.mp4 per job
    thresholds: dict[str, Threshold] = Field(default_factory=dict)

    @field_validator("estimators")
    @classmethod
    def _estimators(cls, v: list[str]) -> list[str]:
        from estimator.egomotion.baselines import check_estimator

        for e in v:
            check_estimator(e)
        if len(set(v)) != len(v):
            raise ValueError(f"estimators listed twice: {v}")
        return v

    @field_validator("detectors")
    @classmethod
    def _detectors(cls, v: list[str]) -> list[str]:
        from estimator.surround.plugin import check_detector

        for d in v:
            check_detector(d)
        if len(set(v)) != len(v):
            raise ValueError(f"detectors listed twice: {v}")
        return v

    @field_validator("overrides")
    @classmethod
    def _overrides(cls, v: dict[str, Any]) -> dict[str, Any]:
        for key, values in v.items():
            check_override_key(key)
            if isinstance(values, list) and not values:
                raise ValueError(f"override {key!r}: an empty sweep")
        return v

    @field_validator("thresholds")
    @classmethod
    def _thresholds(cls, v: dict[str, Threshold]) -> dict[str, Threshold]:
        for key, t in v.items():
            if key not in KNOWN_METRICS:
                raise ValueError(f"unknown metric {key!r}; known: {', '.join(KNOWN_METRICS)}")
            if t.min is None and t.max is None:
                raise ValueError(f"threshold {key!r}: give min, max or both")
        return v

    def sweep(self) -> list[dict[str, Any]]:
        """Every combination of the overrides, as {dotted key: value} (one if none)."""
        keys = list(self.overrides)
        axes = [v if isinstance(v, list) else [v] for v in self.overrides.values()]
        return [dict(zip(keys, combo, strict=True)) for combo in itertools.product(*axes)]

    def swept_keys(self) -> list[str]:
        """Override keys with more than one value."""
        return [k for k, v in self.overrides.items() if isinstance(v, list) and len(v) > 1]


def check_override_key(key: str) -> None:
    """Raise ValueError unless ``key`` is a dotted path into `Scenario`."""
    if key in ("camera", "seed") or key.startswith("camera."):
        raise ValueError(f"override {key!r}: use the suite's 'cameras' / 'seeds' lists")
    if key == "name":
        raise ValueError("override 'name': the scenario name is not an override")
    model: Any = Scenario
    parts = key.split(".")
    for i, part in enumerate(parts):
        fields = model.model_fields
        if part not in fields:
            where = ".".join(parts[:i]) or "scenario"
            raise ValueError(
                f"override {key!r}: {where} has no key {part!r}; known: {', '.join(fields)}"
            )
        ann = fields[part].annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            model = ann
            continue
        if i + 1 < len(parts) and not (ann is dict or getattr(ann, "__origin__", None) is dict):
            raise ValueError(f"override {key!r}: {'.'.join(parts[: i + 1])} is not a section")
        return
    raise ValueError(f"override {key!r}: names a section, not a value")


# ----------------------------------------------------------------- the jobs
@dataclass(frozen=True)
class Job:
    """One scenario x camera x estimator x seed x override combination."""

    job_id: str  # stable hash of (resolved scenario, estimator, frames)
    scenario: Scenario  # resolved: camera, seed and overrides applied
    scenario_source: str  # the suite entry's file
    camera: str  # label: a preset name or "preset(key=value,...)"
    estimator: str
    seed: int
    overrides: dict[str, Any]
    frames: int  # effective frame count
    render_key: str
    video: bool = True
    detector: str = DEFAULT_DETECTOR  # or another of `DETECTOR_METHODS`, or a plug-in

    @property
    def label(self) -> str:
        extra = "".join(f" {k}={v}" for k, v in self.overrides.items())
        if self.detector != DEFAULT_DETECTOR:
            extra += f" detector={self.detector}"
        return f"{self.scenario.name} | {self.camera} | {self.estimator} | seed {self.seed}{extra}"

    @property
    def group(self) -> tuple[str, str]:
        """(scenario, camera): jobs of a group differ in estimator, seed or overrides."""
        return self.scenario.name, self.camera

    @property
    def dirname(self) -> str:
        """Folder of the job under the suite's ``jobs/``: readable and unique."""
        text = f"{self.scenario.name}.{self.camera}.{self.estimator}"
        if self.detector != DEFAULT_DETECTOR:
            text += f".{self.detector}"
        return re.sub(r"[^A-Za-z0-9._=-]+", "_", text)[:80] + f".{self.job_id[:10]}"

    def describe(self) -> dict[str, Any]:
        """JSON-ready description (summary.json, history)."""
        return {
            "job_id": self.job_id,
            "label": self.label,
            "scenario": self.scenario.name,
            "scenario_source": self.scenario_source,
            "camera": self.camera,
            "estimator": self.estimator,
            "detector": self.detector,
            "seed": self.seed,
            "overrides": self.overrides,
            "frames": self.frames,
            "render_key": self.render_key,
            "dir": f"jobs/{self.dirname}",
        }


@dataclass
class Suite:
    spec: SuiteSpec
    path: Path | None
    jobs: list[Job] = field(default_factory=list)

    @property
    def name(self) -> str:
        return self.spec.name

    def thresholds_for(self, job: Job) -> dict[str, Threshold]:
        return {k: t for k, t in self.spec.thresholds.items() if t.applies_to(job.estimator)}


def _hash(obj: Any, n: int) -> str:
    text = json.dumps(obj, sort_keys=True, separators=(",", ":"), default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:n]


@functools.cache
def code_version() -> str:
    """Hash of the sources that shape a render (`RENDER_SOURCES`)."""
    h = hashlib.sha256()
    files = sorted(
        {
            p
            for pattern in RENDER_SOURCES
            for p in REPO_DIR.glob(pattern)
            if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
        }
    )
    for p in files:
        h.update(p.relative_to(REPO_DIR).as_posix().encode() + b"\0")
        h.update(p.read_bytes() + b"\0")
    return h.hexdigest()[:16]


def camera_label(spec: str | dict[str, Any]) -> str:
    if isinstance(spec, str):
        return spec
    rest = ",".join(f"{k}={v}" for k, v in spec.items() if k != "preset")
    return f"{spec.get('preset', 'camera')}({rest})"


def job_id_for(
    scenario: Scenario, estimator: str, frames: int, detector: str = DEFAULT_DETECTOR
) -> str:
    """A job's stable id; the default detector is left out of the hash, so that jobs
    named before detectors could be chosen keep their ids."""
    key = {"scenario": scenario.to_dict(), "estimator": estimator, "frames": frames}
    if detector != DEFAULT_DETECTOR:
        key["detector"] = detector
    return _hash(key, 16)


def render_key_for(scenario: Scenario, frames: int) -> str:
    from estimator.camera.files import camera_to_dict, resolve_camera

    camera = camera_to_dict(*resolve_camera(scenario.camera))
    return _hash(
        {
            "scenario": scenario.to_dict(),
            "frames": frames,
            "camera": camera,
            "code": code_version(),
        },
        20,
    )


def set_dotted(data: dict[str, Any], key: str, value: Any) -> None:
    """``data[a][b] = value`` for key ``a.b`` (creating sections as needed)."""
    parts = key.split(".")
    node = data
    for p in parts[:-1]:
        if not isinstance(node.get(p), dict):
            node[p] = {}
        node = node[p]
    node[parts[-1]] = value


def _is_glob(s: str) -> bool:
    return any(c in s for c in "*?[")


def _is_path(s: str) -> bool:
    return "/" in s or s.endswith((".yaml", ".yml"))


def resolve_entries(entries: list[str], base_dir: Path | None, where: str) -> list[Path]:
    """Scenario files of the suite's ``scenarios`` entries (order kept, no repeats)."""
    out: list[Path] = []
    bases = [b for b in (base_dir, Path.cwd()) if b is not None]
    for i, entry in enumerate(entries):
        found: list[Path] = []
        if _is_glob(entry):
            if _is_path(entry):
                for b in bases:
                    found = sorted(p for p in b.glob(entry) if p.is_file())
                    if found:
                        break
            else:
                found = [
                    LIBRARY_DIR / f"{n}.yaml" for n in fnmatch.filter(known_scenarios(), entry)
                ]
            if not found:
                raise SuiteError(f"{where}: key 'scenarios.{i}': {entry!r} matches no scenario")
        elif _is_path(entry):
            cands = [Path(entry)] if Path(entry).is_absolute() else [b / entry for b in bases]
            found = [c for c in cands if c.is_file()][:1]
            if not found:
                raise SuiteError(
                    f"{where}: key 'scenarios.{i}': scenario file {entry!r} not found "
                    f"(looked in {', '.join(str(b) for b in bases)})"
                )
        else:
            try:
                found = [resolve_scenario_path(entry)]
            except ScenarioError as e:
                raise SuiteError(f"{where}: key 'scenarios.{i}': {e}") from None
        for p in found:
            if p.resolve() not in {q.resolve() for q in out}:
                out.append(p)
    return out


def _read_yaml(path: Path, where: str) -> Any:
    try:
        return yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise SuiteError(f"{where}: not valid YAML: {e}") from None
    except OSError as e:
        raise SuiteError(f"{where}: cannot read: {e}") from None


def resolve_suite_path(name_or_path: str | Path) -> Path:
    """A suite file path, or the name of a shipped suite (scenarios/suites/NAME.yaml)."""
    p = Path(name_or_path)
    if p.is_file():
        return p
    shipped = SUITES_DIR / f"{name_or_path}.yaml"
    if not _is_path(str(name_or_path)) and shipped.is_file():
        return shipped
    known = sorted(q.stem for q in SUITES_DIR.glob("*.yaml"))
    raise SuiteError(f"suite file not found: {name_or_path} (shipped suites: {known})")


def load_suite(name_or_path: str | Path, frames: int | None = None) -> Suite:
    """Read, validate and expand a suite file (``frames`` replaces its frame limit)."""
    path = resolve_suite_path(name_or_path)
    data = _read_yaml(path, str(path))
    if isinstance(data, dict):
        data.setdefault("name", path.stem)
        if frames is not None:
            data["frames"] = frames
    return suite_from_dict(data, where=str(path), base_dir=path.parent, path=path)


def suite_from_dict(
    data: Any, where: str = "<suite>", base_dir: Path | None = None, path: Path | None = None
) -> Suite:
    if not isinstance(data, dict):
        raise SuiteError(f"{where}: a suite must be a mapping, got {type(data).__name__}")
    try:
        spec = SuiteSpec.model_validate(data)
    except ValidationError as e:
        raise SuiteError(format_errors(e, where)) from None
    suite = Suite(spec, path)
    suite.jobs = expand(spec, base_dir, where)
    return suite


def expand(spec: SuiteSpec, base_dir: Path | None, where: str) -> list[Job]:
    """Every job of the suite, in file order (scenario, camera, seed, sweep, estimator)."""
    jobs: list[Job] = []
    seen: dict[str, str] = {}
    for sc_path in resolve_entries(spec.scenarios, base_dir, where):
        raw = _read_yaml(sc_path, str(sc_path))
        if not isinstance(raw, dict):
            raise SuiteError(f"{sc_path}: a scenario must be a mapping")
        for ci, cam in enumerate(spec.cameras or [raw.get("camera", "omni-near")]):
            for seed in spec.seeds or [raw.get("seed", 0)]:
                for combo in spec.sweep():
                    data = copy.deepcopy(raw)
                    data["camera"] = copy.deepcopy(cam)
                    data["seed"] = seed
                    for k, v in combo.items():
                        set_dotted(data, k, copy.deepcopy(v))
                    ctx = f"{where}: scenario {sc_path.name}"
                    if spec.cameras:
                        ctx += f", cameras.{ci} {camera_label(cam)!r}"
                    if combo:
                        ctx += f", overrides {combo}"
                    try:
                        sc = scenario_from_dict(data, where=ctx)
                    except ScenarioError as e:
                        raise SuiteError(str(e)) from None
                    n = sc.n_frames if spec.frames is None else min(sc.n_frames, spec.frames)
                    rkey = render_key_for(sc, n)
                    for est, det in itertools.product(spec.estimators, spec.detectors):
                        jid = job_id_for(sc, est, n, det)
                        job = Job(
                            job_id=jid,
                            scenario=sc,
                            scenario_source=str(sc_path),
                            camera=camera_label(cam),
                            estimator=est,
                            seed=sc.seed,
                            overrides=combo,
                            frames=n,
                            render_key=rkey,
                            video=spec.video,
                            detector=det,
                        )
                        if jid in seen:  # e.g. a glob and a name for the same scenario
                            continue
                        seen[jid] = job.label
                        jobs.append(job)
    return jobs


def suite_fingerprint(suite: Suite) -> str:
    """Hash of the job ids: two runs of the same suite share it."""
    return _hash(sorted(j.job_id for j in suite.jobs), 16)
