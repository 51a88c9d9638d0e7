"""Which faces the outline sees: depths behind a box's camera-facing faces, and a rendered
drive's records."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from scenarios.config import load_scenario
from scenarios.detection_metrics import BAND_NAMES
from scenarios.outline_faces import drive_faces, face_depths, main, summary
from sim.drive import render_drive

# a 5 x 2 m car ahead and to the right: its rear face at x = 6.5, its near side at y = -3
CAR = np.array([[6.5, -5.0], [11.5, -5.0], [11.5, -3.0], [6.5, -3.0]])


def _segment(a, b, n=9):
    return np.linspace(a, b, n)


def test_points_on_the_near_faces_are_at_depth_zero():
    side = _segment([7.0, -3.0], [11.0, -3.0])  # along the near side
    end = _segment([6.5, -3.2], [6.5, -4.8])  # across the rear
    assert face_depths(side, CAR)[0] == pytest.approx(0.0, abs=1e-9)
    assert face_depths(end, CAR)[1] == pytest.approx(0.0, abs=1e-9)


def test_points_on_the_far_faces_are_a_width_and_a_length_deep():
    far_side = _segment([7.0, -5.0], [11.0, -5.0])
    far_end = _segment([11.5, -3.2], [11.5, -4.8])
    assert face_depths(far_side, CAR)[0] == pytest.approx(2.0)
    assert face_depths(far_end, CAR)[1] == pytest.approx(5.0)
    # the far corner of the rear face: on the end face, a width behind the side face
    corner = _segment([6.5, -4.6], [6.5, -5.0], 3)
    side, end = face_depths(corner, CAR)
    assert side == pytest.approx(1.8) and end == pytest.approx(0.0)


def test_an_axis_whose_span_holds_the_camera_has_no_face():
    alongside = np.array([[-2.5, 3.0], [2.5, 3.0], [2.5, 5.0], [-2.5, 5.0]])
    side, end = face_depths(_segment([-2.0, 3.0], [2.0, 3.0]), alongside)
    assert side == pytest.approx(0.0, abs=1e-9) and math.isnan(end)


@settings(max_examples=40, deadline=None)
@given(st.floats(-math.pi, math.pi), st.floats(0.0, 1.0), st.floats(0.0, 1.0))
def test_depths_do_not_depend_on_where_the_scene_is_turned(angle, s, t):
    """Turning the car and the points together about the camera keeps every depth."""
    c, sn = math.cos(angle), math.sin(angle)
    R = np.array([[c, -sn], [sn, c]])
    pts = np.array([[6.5 + 5.0 * s, -3.0 - 2.0 * t], [6.5, -3.0 - 2.0 * s], [9.0, -3.0]])
    a = face_depths(pts, CAR)
    b = face_depths(pts @ R.T, CAR @ R.T)
    assert np.allclose(a, b, atol=1e-9)


def test_a_rendered_dense_drive(tmp_path):
    """The dense freeway's first frames: vehicle detections with outlines, each against an
    evaluated vehicle in range; the summary counts them once per band."""
    render_drive(load_scenario("dense-freeway-omni-near"), tmp_path, progress=False, max_frames=16)
    recs = drive_faces(tmp_path)
    assert recs, "the dense freeway has vehicle detections by its 16th frame"
    assert all(0.0 <= r["range_m"] <= 25.0 and 1 <= r["frame"] < 16 for r in recs)
    assert all(math.isfinite(r["side_m"]) or math.isfinite(r["end_m"]) for r in recs)
    res = summary(recs)
    assert res["all"]["detections"] == len(recs)
    assert sum(res[b]["detections"] for b in BAND_NAMES) == len(recs)
    with pytest.raises(ValueError, match="every"):
        drive_faces(tmp_path, every=0)


@pytest.mark.parametrize(
    ("args", "message"),
    [(["--every", "0"], "--every must be >= 1"), ([], "is not a complete drive")],
)
def test_the_command_names_bad_input_before_any_work(tmp_path, capsys, args, message):
    with pytest.raises(SystemExit) as e:
        main([str(tmp_path / "nowhere"), *args])
    assert e.value.code == 2 and message in capsys.readouterr().err
