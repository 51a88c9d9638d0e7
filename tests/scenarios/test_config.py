"""Scenario files: validation errors name the file, the key and the value."""

from pathlib import Path

import pytest

from scenarios.config import ScenarioError, known_scenarios, load_scenario

SHIPPED = known_scenarios()


def test_ships_every_env_for_both_omni_cameras_and_a_rectilinear_drive():
    for env in ("highway", "merge", "roundabout", "racetrack", "intersection"):
        for cam in ("omni-near", "omni-far"):
            assert f"{env}-{cam}" in SHIPPED
    assert "highway-rectilinear" in SHIPPED


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_scenarios_load(name):
    sc = load_scenario(name)
    assert sc.name == name
    assert sc.n_frames == int(sc.duration_s * sc.fps)


def test_dense_drives_ship_for_the_surround_suites():
    dense = [n for n in SHIPPED if n.startswith("dense-")]
    assert len(dense) == 5
    assert load_scenario("dense-freeway-omni-near").ego_speed_mps == 19.0


def test_an_unset_ego_speed_is_left_out_of_the_scenario_data():
    """Renders and suite jobs keyed by the scenario data keep their keys."""
    assert "ego_speed_mps" not in load_scenario("highway-omni-near").to_dict()
    assert load_scenario("dense-freeway-omni-near").to_dict()["ego_speed_mps"] == 19.0


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "s.yaml"
    p.write_text(text)
    return p


def test_path_from_anywhere(tmp_path):
    p = _write(tmp_path, "name: x\nenv: merge-v0\ncamera: omni-far\n")
    assert load_scenario(str(p)).env == "merge-v0"


def test_unknown_key_is_named(tmp_path):
    p = _write(tmp_path, "name: x\nsensor: {noise_sdt: 2}\n")
    with pytest.raises(ScenarioError, match=r"s\.yaml.*sensor\.noise_sdt"):
        load_scenario(p)


def test_bad_value_is_named(tmp_path):
    p = _write(tmp_path, "name: x\nfps: -3\n")
    with pytest.raises(ScenarioError, match=r"key 'fps'.*-3"):
        load_scenario(p)


def test_unknown_env_is_named(tmp_path):
    p = _write(tmp_path, "name: x\nenv: highwey-v0\n")
    with pytest.raises(ScenarioError, match=r"key 'env'.*highwey-v0"):
        load_scenario(p)


def test_unknown_camera_preset_lists_known(tmp_path):
    p = _write(tmp_path, "name: x\ncamera: omni-middle\n")
    with pytest.raises(ScenarioError, match=r"key 'camera'.*omni-middle"):
        load_scenario(p)


def test_inline_camera_overrides(tmp_path):
    p = _write(tmp_path, "name: x\ncamera: {preset: omni-far, width: 800, height: 800}\n")
    from estimator.camera.files import resolve_camera

    cam, _ = resolve_camera(load_scenario(p).camera)
    assert (cam.width, cam.height) == (800, 800)


def test_missing_file_and_bad_yaml(tmp_path):
    with pytest.raises(ScenarioError, match="not found"):
        load_scenario(tmp_path / "nope.yaml")
    p = _write(tmp_path, "name: [unclosed\n")
    with pytest.raises(ScenarioError, match="not valid YAML"):
        load_scenario(p)
    p = _write(tmp_path, "- a list\n")
    with pytest.raises(ScenarioError, match="mapping"):
        load_scenario(p)
