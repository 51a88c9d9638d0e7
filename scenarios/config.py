"""Scenario files: the shipped library (`scenarios/library/`) and YAML loading.

The schema itself (`Scenario` and its CAN, vibration and sensor models) is
`sim.scenario`; it is re-exported here for the scenarios' own callers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml

from sim.scenario import (  # noqa: F401  (re-exported)
    CanConfig,
    Scenario,
    ScenarioError,
    SensorConfig,
    VibrationConfig,
    scenario_from_dict,
)

LIBRARY_DIR = Path(__file__).parent / "library"


def known_scenarios() -> list[str]:
    """Names of the scenarios shipped in scenarios/library/."""
    return sorted(p.stem for p in LIBRARY_DIR.glob("*.yaml"))


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A path to a YAML file (from anywhere), or the name of a shipped scenario."""
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") or p.exists():
        if not p.is_file():
            raise ScenarioError(f"scenario file not found: {p}")
        return p
    lib = LIBRARY_DIR / f"{name_or_path}.yaml"
    if lib.is_file():
        return lib
    raise ScenarioError(
        f"unknown scenario {str(name_or_path)!r}: not a file, and not one of the shipped "
        f"scenarios {known_scenarios()}"
    )


def load_scenario(name_or_path: str | Path, **overrides: Any) -> Scenario:
    """Load, validate and (optionally) override a scenario."""
    path = resolve_scenario_path(name_or_path)
    try:
        data = yaml.safe_load(path.read_text())
    except yaml.YAMLError as e:
        raise ScenarioError(f"{path}: not valid YAML: {e}") from None
    if isinstance(data, dict):
        data = {**data, **overrides}
    return scenario_from_dict(data, where=str(path))
