"""Camera files, presets and override specs."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from estimator.camera.files import (
    PRESETS_DIR,
    CameraFileError,
    camera_to_dict,
    load_body_mask,
    load_camera,
    preset_names,
    resolve_camera,
    save_camera,
    with_folder_body_mask,
)
from estimator.camera.models import HyperbolicCamera, PinholeCamera
from estimator.camera.mount import CameraMount


def write(path: Path, data) -> Path:
    path.write_text(yaml.safe_dump(data) if not isinstance(data, str) else data)
    return path


def preset_dict(name: str) -> dict:
    return yaml.safe_load((PRESETS_DIR / f"{name}.yaml").read_text())


# ------------------------------------------------------------------ presets
def test_preset_names():
    assert preset_names() == ["omni-far", "omni-near", "rectilinear-rear-left"]


@pytest.mark.parametrize("name,elev", [("omni-near", 5.0), ("omni-far", 15.0)])
def test_omni_presets(name, elev):
    cam, mount = load_camera(name)
    assert isinstance(cam, HyperbolicCamera)
    assert (cam.width, cam.height, cam.max_elevation_deg, cam.body_mask_deg) == (
        640,
        640,
        elev,
        75.0,
    )
    # the stored focal lengths are what from_fov gives (rim 8 px inside the image)
    ref = HyperbolicCamera.from_fov(0.04, 0.03, 640, 640, elev, rim_margin_px=8.0)
    assert cam == ref
    assert mount == CameraMount((0.0, 0.0, 1.95), 0.0, 0.0, 0.0, "omni")
    np.testing.assert_allclose(mount.K0, [0, 0, 1 / 1.95])


def test_rectilinear_preset():
    cam, mount = load_camera("rectilinear-rear-left")
    assert cam == PinholeCamera(420.0, 420.0, 319.5, 239.5, 0.0, 640, 480)
    assert mount == CameraMount((0.3, 0.95, 1.2), 160.0, 15.0, 0.0, "pinhole")


def test_load_by_path(tmp_path):
    path = write(tmp_path / "cam.yaml", preset_dict("omni-far"))
    assert load_camera(path) == load_camera("omni-far")
    assert load_camera(str(path)) == load_camera("omni-far")


def test_defaults_fill_optional_fields(tmp_path):
    path = write(
        tmp_path / "cam.yaml", {"model": "pinhole", "fu": 400, "fv": 400, "u0": 1, "v0": 2}
    )
    cam, mount = load_camera(path)
    assert (cam.width, cam.height, cam.skew) == (640, 480, 0.0)
    assert mount.base == "pinhole" and mount.position_m == (0.0, 0.0, 1.95)


# ------------------------------------------------------------------- saving
@pytest.mark.parametrize("name", ["omni-near", "rectilinear-rear-left"])
def test_save_load_round_trip(tmp_path, name):
    cam, mount = load_camera(name)
    cam = cam.replace(u0=cam.u0 + 0.123456789, skew=1e-5)
    path = tmp_path / "sub" / "camera.yaml"
    assert save_camera(path, cam, mount) == path
    assert load_camera(path) == (cam, mount)
    save_camera(path, cam.replace(fu=cam.fu * 2), mount)  # overwrite in place
    assert load_camera(path)[0].fu == cam.fu * 2
    assert sorted(p.name for p in path.parent.iterdir()) == ["camera.yaml"]  # no temp files left


def test_rear_axle_round_trip(tmp_path):
    """The optional rear axle (kinematic constraint) is saved only when known."""
    cam, mount = load_camera("omni-near")
    assert mount.rear_axle_x_m is None and mount.lever_arm_m is None
    assert "rear_axle_x_m" not in mount.to_dict()
    with_axle = replace(mount, rear_axle_x_m=-2.5)
    assert with_axle.lever_arm_m == pytest.approx(2.5)
    path = save_camera(tmp_path / "camera.yaml", cam, with_axle)
    assert load_camera(path) == (cam, with_axle)
    with pytest.raises(ValueError, match="rear_axle_x_m"):
        replace(mount, rear_axle_x_m=float("nan"))


@pytest.mark.parametrize("name", ["omni-near", "rectilinear-rear-left"])
def test_vignetting_round_trip(tmp_path, name):
    """The photometric calibration travels with the camera file; presets have none."""
    cam, mount = load_camera(name)
    assert cam.vignetting == 0.0 and np.all(cam.vignetting_gain() == 1.0)
    cam = cam.replace(vignetting=0.25)
    path = save_camera(tmp_path / "camera.yaml", cam, mount)
    assert "vignetting: 0.25" in path.read_text()
    assert load_camera(path) == (cam, mount)
    gain = cam.vignetting_gain()
    assert gain.shape == (cam.height, cam.width) and not gain.flags.writeable
    h, w = cam.height, cam.width
    corners = gain[[0, 0, h - 1, h - 1], [0, w - 1, 0, w - 1]]
    assert np.allclose(corners, 0.75) and gain.max() == pytest.approx(1.0, abs=1e-5)


def test_save_refuses_mismatched_mount(tmp_path):
    cam, _ = load_camera("omni-near")
    _, pin_mount = load_camera("rectilinear-rear-left")
    with pytest.raises(ValueError, match="does not match"):
        save_camera(tmp_path / "x.yaml", cam, pin_mount)
    assert not (tmp_path / "x.yaml").exists()
    with pytest.raises(TypeError, match="CameraMount"):
        camera_to_dict(cam, {"base": "omni"})


# ------------------------------------------------------------------ resolve
def test_resolve_name_and_plain_mapping():
    assert resolve_camera("omni-near") == load_camera("omni-near")
    full = preset_dict("rectilinear-rear-left")
    assert resolve_camera(full) == load_camera("rectilinear-rear-left")


def test_resolve_overrides_omni():
    base, _ = load_camera("omni-far")
    cam, mount = resolve_camera(
        {"preset": "omni-far", "a": 0.05, "width": 800, "height": 800, "mount_height_m": 2.1}
    )
    assert (cam.a, cam.b, cam.width, cam.height) == (0.05, 0.03, 800, 800)
    # rim kept 8 px * (800/640) = 10 px inside the image, centred
    assert cam == HyperbolicCamera.from_fov(0.05, 0.03, 800, 800, 15.0, rim_margin_px=10.0)
    assert mount.position_m == (0.0, 0.0, 2.1)
    # explicit values win over the rescaling
    cam2, _ = resolve_camera({"preset": "omni-far", "width": 800, "height": 800, "u0": 390.0})
    assert cam2.u0 == 390.0 and cam2.v0 == 399.5
    # nothing geometric changed: the preset's intrinsics are kept as they are
    cam3, _ = resolve_camera({"preset": "omni-far", "body_mask_deg": 70.0})
    assert cam3 == base.replace(body_mask_deg=70.0)


def test_resolve_overrides_pinhole():
    cam, mount = resolve_camera(
        {"preset": "rectilinear-rear-left", "width": 1280, "height": 960, "mount": {"yaw_deg": 150}}
    )
    assert cam == PinholeCamera(840.0, 840.0, 639.5, 479.5, 0.0, 1280, 960)
    assert mount == CameraMount((0.3, 0.95, 1.2), 150.0, 15.0, 0.0, "pinhole")
    # same field of view after resampling: corner rays agree
    base, _ = load_camera("rectilinear-rear-left")
    np.testing.assert_allclose(
        cam.unproject(np.array([[-0.5, -0.5]])), base.unproject(np.array([[-0.5, -0.5]]))
    )


def test_resolve_from_a_file_preset(tmp_path):
    path = write(tmp_path / "cam.yaml", preset_dict("omni-near"))
    cam, _ = resolve_camera({"preset": str(path), "body_mask_deg": 60.0})
    assert cam.body_mask_deg == 60.0


# ------------------------------------------------------------------- errors
def test_unknown_preset_lists_known():
    with pytest.raises(CameraFileError) as e:
        load_camera("omni-middle")
    msg = str(e.value)
    assert "'omni-middle'" in msg and "omni-far, omni-near, rectilinear-rear-left" in msg
    with pytest.raises(ValueError, match="unknown camera preset 'nope'; known presets: omni-far"):
        resolve_camera({"preset": "nope"})


def test_missing_file_is_named(tmp_path):
    with pytest.raises(CameraFileError, match=r"camera file '.*missing\.yaml' not found"):
        load_camera(tmp_path / "missing.yaml")


def test_unknown_yaml_key_names_file_key_and_value(tmp_path):
    data = preset_dict("omni-near")
    data["focal"] = 3.0
    path = write(tmp_path / "bad.yaml", data)
    with pytest.raises(ValueError) as e:
        load_camera(path)
    msg = str(e.value)
    assert str(path) in msg and "unknown key 'focal'" in msg and "3.0" in msg
    assert "allowed keys: model, a, b" in msg


def test_unknown_nested_key(tmp_path):
    data = preset_dict("omni-near")
    data["mount"]["yaw"] = 5
    path = write(tmp_path / "bad.yaml", data)
    with pytest.raises(ValueError, match=r"unknown key 'mount.yaw' \(value 5\).*yaw_deg"):
        load_camera(path)


@pytest.mark.parametrize(
    "key,value,match",
    [
        ("width", 640.5, r"key 'width': Input should be a valid integer, got 640.5"),
        ("a", "0.04", r"key 'a': .*valid number, got '0.04'"),
        ("a", -0.04, r"camera parameter a must be > 0, got -0.04"),
        ("model", "fisheye", r"key 'model': unknown camera model 'fisheye'"),
        ("max_elevation_deg", 80.0, r"max_elevation_deg must be in"),
        ("vignetting", 1.0, r"vignetting must be in \[0, 1\).*got 1.0"),
        ("vignetting", -0.1, r"camera parameter vignetting must be >= 0, got -0.1"),
        ("vignetting", "0.2", r"key 'vignetting': .*valid number, got '0.2'"),
    ],
)
def test_bad_values_name_file_key_and_value(tmp_path, key, value, match):
    data = preset_dict("omni-near")
    data[key] = value
    path = write(tmp_path / "bad.yaml", data)
    with pytest.raises(ValueError, match=match) as e:
        load_camera(path)
    assert str(path) in str(e.value)


def test_structural_errors(tmp_path):
    data = preset_dict("omni-near")
    del data["fu"]
    with pytest.raises(ValueError, match="missing key 'fu'"):
        load_camera(write(tmp_path / "a.yaml", data))
    data = preset_dict("omni-near")
    data["mount"]["base"] = "pinhole"
    with pytest.raises(ValueError, match="'mount.base': 'pinhole' does not match"):
        load_camera(write(tmp_path / "b.yaml", data))
    data["mount"] = {"position_m": [0.0, 0.0, -1.0]}
    with pytest.raises(ValueError, match="mount height"):
        load_camera(write(tmp_path / "c.yaml", data))
    with pytest.raises(ValueError, match=r"invalid YAML at line \d+"):
        load_camera(write(tmp_path / "d.yaml", "model: [hyperbolic\n"))
    with pytest.raises(ValueError, match="empty"):
        load_camera(write(tmp_path / "e.yaml", ""))
    with pytest.raises(ValueError, match="expected a mapping"):
        load_camera(write(tmp_path / "f.yaml", "- 1\n- 2\n"))


def test_resolve_errors():
    with pytest.raises(ValueError, match=r"unknown key 'foo' \(value 1\)"):
        resolve_camera({"preset": "omni-near", "foo": 1})
    with pytest.raises(ValueError, match=r"key 'mount_height_m'.*got 'high'"):
        resolve_camera({"preset": "omni-near", "mount_height_m": "high"})
    with pytest.raises(ValueError, match="either 'mount_height_m'"):
        resolve_camera(
            {"preset": "omni-near", "mount_height_m": 2.0, "mount": {"position_m": [0, 0, 2]}}
        )
    with pytest.raises(ValueError, match="unknown key 'a'"):
        resolve_camera({"preset": "rectilinear-rear-left", "a": 0.04})
    with pytest.raises(ValueError, match=r"camera spec must be .*got int 3"):
        resolve_camera(3)
    with pytest.raises(ValueError, match=r"preset 'omni-near'.*max_elevation_deg must be in"):
        resolve_camera({"preset": "omni-near", "max_elevation_deg": 70.0})
    with pytest.raises(ValueError, match=r"preset 'omni-near'.*mount height"):
        resolve_camera({"preset": "omni-near", "mount_height_m": -1.0})


# ------------------------------------------------------------------ body mask
def test_body_mask_file_round_trip_and_errors(tmp_path):
    cam, _ = load_camera("omni-near")
    body = np.zeros((cam.height, cam.width), np.uint8)
    body[300:340, 290:350] = 255
    path = tmp_path / "body_mask.png"
    cv2.imwrite(str(path), body)
    np.testing.assert_array_equal(load_body_mask(path, cam), body > 0)
    seen = with_folder_body_mask(cam, tmp_path)  # the folder holds body_mask.png
    assert not seen.valid_mask()[body > 0].any() and seen.valid_mask()[10, 320]
    assert with_folder_body_mask(cam, tmp_path / "none") is cam  # a folder without one
    cv2.imwrite(str(tmp_path / "small.png"), body[:100])
    with pytest.raises(CameraFileError, match=r"small.png: body mask is 640x100"):
        load_body_mask(tmp_path / "small.png", cam)
    cv2.imwrite(str(tmp_path / "empty.png"), body * 0)
    with pytest.raises(CameraFileError, match="empty.png: body mask marks no pixel"):
        load_body_mask(tmp_path / "empty.png", cam)
    with pytest.raises(CameraFileError, match="missing.png: cannot read"):
        load_body_mask(tmp_path / "missing.png", cam)
