"""Camera models: round trips, Jacobians, independent models, conventions, bad input."""

from __future__ import annotations

import functools

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.camera.files import load_camera
from estimator.camera.models import (
    CameraModel,
    HyperbolicCamera,
    PinholeCamera,
    check_pixels,
    check_points,
    row_norm,
)

PRESETS = ["omni-near", "omni-far", "rectilinear-rear-left"]


@functools.cache
def cached_camera(name: str) -> CameraModel:
    return load_camera(name)[0]


@pytest.fixture(scope="module", params=PRESETS)
def preset(request):
    return load_camera(request.param)


def central_differences(cam: CameraModel, P: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """(N, 2, 3) dw/dP by central differences (step relative to |P|), float64."""
    step = h * np.linalg.norm(P, axis=1, keepdims=True)
    cols = []
    for i in range(3):
        e = np.zeros(3)
        e[i] = 1.0
        cols.append((cam.project(P + step * e) - cam.project(P - step * e)) / (2 * step))
    return np.stack(cols, axis=-1)


def mei_project(P: np.ndarray, xi: float, gu: float, gv: float, s: float, u0: float, v0: float):
    """Mei's unified model (Mei & Rives 2007, no distortion), written independently.

    Points go to the unit sphere, are reprojected from (0, 0, -xi), then K.
    """
    Xs = P / np.linalg.norm(P, axis=1, keepdims=True)
    mx = Xs[:, 0] / (Xs[:, 2] + xi)
    my = Xs[:, 1] / (Xs[:, 2] + xi)
    return np.stack([gu * mx + s * my + u0, gv * my + v0], axis=1)


def mirror_ray_trace(P: np.ndarray, a: float, b: float) -> np.ndarray:
    """(N, 2) image coordinates p of rays by reflecting them off the hyperboloid.

    Mirror (eq. 5) ``(Z - c)^2/a^2 - (X^2+Y^2)/b^2 = 1``, viewpoint at the focus
    O = 0, pinhole at the other focus F = (0, 0, 2c) looking along -Z with unit
    focal length (image flipped so that p has the sign of (X, Y)). Also checks
    the law of reflection at each mirror point.
    """
    c = np.hypot(a, b)
    out = []
    for d in P / np.linalg.norm(P, axis=1, keepdims=True):
        X, Y, Z = d
        # |t d| on the mirror: (tZ - c)^2 b^2 - t^2 (X^2 + Y^2) a^2 = a^2 b^2
        coeffs = [Z * Z * b * b - (X * X + Y * Y) * a * a, -2 * Z * c * b * b, b**4]
        roots = np.roots(coeffs)
        t = min(r.real for r in roots if abs(r.imag) < 1e-12 and r.real > 0)
        M = t * d
        assert M[2] < c  # on the sheet that faces the viewpoint
        normal = np.array([-2 * M[0] / b**2, -2 * M[1] / b**2, 2 * (M[2] - c) / a**2])
        normal /= np.linalg.norm(normal)
        incoming = -d  # light travels towards O
        reflected = incoming - 2 * np.dot(incoming, normal) * normal
        to_focus = np.array([0, 0, 2 * c]) - M
        np.testing.assert_allclose(reflected, to_focus / np.linalg.norm(to_focus), atol=1e-12)
        out.append(M[:2] / (2 * c - M[2]))
    return np.array(out)


# ------------------------------------------------------------------ smoke/shape
def test_shapes_and_kinds(preset):
    cam, mount = preset
    assert cam.kind == mount.base
    P = cam.unproject(np.array([[cam.width / 2 + 100.5, cam.height / 2 - 3.0]]))
    assert P.shape == (1, 3)
    assert cam.project(P).shape == (1, 2)
    assert cam.project_jacobian(P).shape == (1, 2, 3)
    assert cam.valid_rays(P).shape == (1,)
    assert cam.project(np.zeros((0, 3))).shape == (0, 2)
    assert cam.valid_mask().shape == (cam.height, cam.width)
    assert cam.valid_mask().dtype == bool
    rays = cam.pixel_rays()
    assert rays.shape == (cam.height, cam.width, 3) and rays.dtype == np.float32
    np.testing.assert_allclose(np.linalg.norm(rays, axis=-1), 1.0, atol=1e-6)


def test_masks_and_rays_are_cached_and_read_only(preset):
    cam, _ = preset
    assert cam.valid_mask() is cam.valid_mask()
    assert cam.pixel_rays() is cam.pixel_rays()
    with pytest.raises(ValueError):
        cam.valid_mask()[0, 0] = True
    with pytest.raises(ValueError):
        cam.pixel_rays()[0, 0, 0] = 1.0


# ----------------------------------------------------------------- round trips
def test_round_trip_whole_valid_image(preset):
    """Acceptance: project(unproject(w)) == w to 1e-6 px on every valid pixel."""
    cam, _ = preset
    w = cam.pixel_grid()[cam.valid_mask()]
    assert len(w) > 0.1 * cam.width * cam.height
    P = cam.unproject(w)
    np.testing.assert_allclose(np.linalg.norm(P, axis=1), 1.0, atol=1e-12)
    assert np.all(cam.valid_rays(P))
    assert np.abs(cam.project(P) - w).max() < 1e-6


def test_round_trip_outside_the_mask_too(preset):
    """Every pixel (also outside the field of view) has a ray, and it maps back."""
    cam, _ = preset
    w = cam.pixel_grid().reshape(-1, 2)[::7]
    assert np.abs(cam.project(cam.unproject(w)) - w).max() < 1e-6


def test_pixel_rays_match_unproject(preset):
    cam, _ = preset
    w = cam.pixel_grid()
    np.testing.assert_allclose(
        cam.pixel_rays().reshape(-1, 3), cam.unproject(w.reshape(-1, 2)), atol=1e-6
    )


# ------------------------------------------------------------------- Jacobian
def test_jacobian_matches_central_differences(preset):
    """Acceptance: analytic dw/dP == central differences to 1e-5 relative."""
    cam, _ = preset
    rng = np.random.default_rng(7)
    w = cam.pixel_grid()[cam.valid_mask()]
    w = w[rng.choice(len(w), 2000, replace=False)]
    P = cam.unproject(w) * rng.uniform(0.5, 30.0, (len(w), 1))  # scale does not matter
    J = cam.project_jacobian(P)
    Jn = central_differences(cam, P)
    rel = np.linalg.norm(J - Jn, axis=(1, 2)) / np.linalg.norm(J, axis=(1, 2))
    assert rel.max() < 1e-5


def test_omni_jacobian_is_scale_free():
    """p does not depend on |P|, so dp/dP . P = 0 (Euler): the printed Table 1 breaks it."""
    cam, _ = load_camera("omni-near")
    P = cam.unproject(cam.pixel_grid()[cam.valid_mask()][::50]) * 3.7
    np.testing.assert_allclose(np.einsum("nij,nj->ni", cam.project_jacobian(P), P), 0, atol=1e-9)


def test_table1_row4_as_printed_has_wrong_signs():
    """Table 1 row 4 as printed: first two columns negated, third column wrong.

    Reference: paper Table 1, ``dp/dP = 1/((q2 Z + q3|P|)|P|) [[q3xX - q1|P|,
    q3xY, q3xZ], [q3yX, q3yY - q1|P|, q3yZ]]``.
    """
    cam = HyperbolicCamera.from_fov(0.04, 0.03)
    rng = np.random.default_rng(3)
    P = rng.normal(size=(50, 3))
    P[:, 2] = np.abs(P[:, 2])  # below the horizon: well inside the model's domain
    X, Y, Z = P.T
    n = np.linalg.norm(P, axis=1)
    den = (cam.q2 * Z + cam.q3 * n) * n
    x = cam.q1 * X / (cam.q2 * Z + cam.q3 * n)
    y = cam.q1 * Y / (cam.q2 * Z + cam.q3 * n)
    printed = (
        np.stack(
            [
                np.stack([cam.q3 * x * X - cam.q1 * n, cam.q3 * x * Y, cam.q3 * x * Z], 1),
                np.stack([cam.q3 * y * X, cam.q3 * y * Y - cam.q1 * n, cam.q3 * y * Z], 1),
            ],
            1,
        )
        / den[:, None, None]
    )
    Kp = np.array([[cam.fu, cam.skew], [0.0, cam.fv]])
    Jp_fd = np.linalg.solve(Kp, central_differences(cam, P))  # dp/dP by differences
    np.testing.assert_allclose(-printed[:, :, :2], Jp_fd[:, :, :2], rtol=1e-6, atol=1e-9)
    assert not np.allclose(printed[:, :, 2], Jp_fd[:, :, 2], atol=1e-3)
    assert not np.allclose(-printed[:, :, 2], Jp_fd[:, :, 2], atol=1e-3)


# ----------------------------------------------------------- eq. 10 (inverse)
def test_eq10_as_printed_is_the_exact_inverse_with_sign():
    """eq. 10 returns q1^2/(q2 Z + q3) * P for unit P: a positive multiple."""
    cam = HyperbolicCamera.from_fov(0.04, 0.03)
    rng = np.random.default_rng(11)
    P = rng.normal(size=(500, 3))
    P /= np.linalg.norm(P, axis=1, keepdims=True)
    P = P[P[:, 2] > -cam.xi + 1e-3]
    p = (cam.project(P) - [cam.u0, cam.v0]) / [cam.fu, cam.fv]
    x, y = p.T
    eq10 = np.stack([cam.q1 * x, cam.q1 * y, cam.q2 - cam.q3 * np.sqrt(x * x + y * y + 1)], 1)
    scale = cam.q1**2 / (cam.q2 * P[:, 2] + cam.q3)
    assert np.all(scale > 0)
    np.testing.assert_allclose(eq10, scale[:, None] * P, rtol=1e-9, atol=1e-15)


# ------------------------------------------------------- independent models
@pytest.mark.parametrize("name", ["omni-near", "omni-far"])
def test_hyperbolic_equals_mei_unified_model(name):
    """cv2.omnidir is absent (opencv-python-headless): numpy Mei formula instead."""
    cam, _ = load_camera(name)
    cam = cam.replace(skew=1.5, fv=cam.fv * 1.01)
    w = cam.pixel_grid()[cam.valid_mask()][::13]
    P = cam.unproject(w) * 5.0
    q1, q2, q3 = cam.q1, cam.q2, cam.q3
    xi, r = q3 / q2, q1 / q2  # eq. 6 as Mei's model: xi = q3/q2, gamma = f q1/q2
    ref = mei_project(P, xi, cam.fu * r, cam.fv * r, cam.skew * r, cam.u0, cam.v0)
    np.testing.assert_allclose(cam.project(P), ref, atol=1e-9)


def test_eq6_matches_a_ray_traced_mirror():
    """Reflect rays off the hyperboloid of eq. 5 into a pinhole at the second focus."""
    cam = HyperbolicCamera(0.04, 0.03, 1.0, 1.0, 0.0, 0.0, max_elevation_deg=15.0)
    rng = np.random.default_rng(5)
    elev = np.radians(rng.uniform(-89.0, 15.0, 40))
    az = rng.uniform(0, 2 * np.pi, 40)
    P = np.stack([np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), -np.sin(elev)], 1)
    np.testing.assert_allclose(cam.project(P), mirror_ray_trace(P, cam.a, cam.b), atol=1e-12)


def test_from_unified_inverts_xi_and_gamma():
    cam = HyperbolicCamera.from_fov(0.04, 0.03)
    back = HyperbolicCamera.from_unified(cam.xi, cam.gamma_u, cam.gamma_v, cam.u0, cam.v0, a=0.04)
    assert back.b == pytest.approx(0.03, rel=1e-12)
    assert back.fu == pytest.approx(cam.fu, rel=1e-12)


# ------------------------------------------------------------ conventions
def car_to_cam(mount, p_car: np.ndarray) -> np.ndarray:
    return (np.asarray(p_car, float) - mount.position_m) @ mount.R_car_cam


def test_ground_point_ahead_lands_above_centre():
    """CONVENTIONS.md: in the omni image the car's front is up (smaller v), right is right."""
    cam, mount = load_camera("omni-near")
    ahead, right, left, behind = car_to_cam(
        mount, [[10.0, 0, 0], [0, -10.0, 0], [0, 10.0, 0], [-10.0, 0, 0]]
    )
    np.testing.assert_allclose(ahead, [0.0, -10.0, 1.95], atol=1e-12)
    w = cam.project(np.array([ahead, right, left, behind]))
    # expected radius from the independent Mei formula: 10 m ahead, 1.95 m below
    r = mei_project(ahead[None], cam.xi, cam.gamma_u, cam.gamma_v, 0, 0, 0)[0, 1]
    assert r == pytest.approx(-10.0 * cam.gamma_v / (1.95 + cam.xi * np.hypot(10.0, 1.95)))
    # by hand: gamma_v = 1267.613 * 0.0009/0.0041 = 278.25 px, xi = 0.0040/0.0041 = 0.97561,
    # |P| = 10.188 m: r = -10 * 278.25 / (1.95 + 0.97561 * 10.188) = -234.03 px
    assert r == pytest.approx(-234.03, abs=0.01)
    np.testing.assert_allclose(w[0], [cam.u0, cam.v0 + r], atol=1e-9)  # up
    np.testing.assert_allclose(w[1], [cam.u0 - r, cam.v0], atol=1e-9)  # right
    np.testing.assert_allclose(w[2], [cam.u0 + r, cam.v0], atol=1e-9)  # left
    np.testing.assert_allclose(w[3], [cam.u0, cam.v0 - r], atol=1e-9)  # down
    assert cam.valid_rays(np.array([ahead, right, left, behind])).all()


def test_omni_centre_sees_straight_down_and_is_masked():
    cam, mount = load_camera("omni-far")
    centre = cam.unproject(np.array([[cam.u0, cam.v0]]))
    np.testing.assert_allclose(centre, [[0, 0, 1]], atol=1e-12)
    np.testing.assert_allclose(mount.R_car_cam @ centre[0], [0, 0, -1], atol=1e-12)
    assert not cam.valid_rays(centre)[0]
    # the car roof, 0.45 m below the viewpoint and 1 m to the side, is in the body disc
    roof_edge = car_to_cam(mount, [[0.0, -1.0, 1.5], [2.5, 0.0, 1.0]])
    assert not cam.valid_rays(roof_edge).any()


def test_body_mask_replaces_the_body_cone():
    """`with_body_mask`: the valid pixels are the field of view less the given body
    pixels, wherever the cone was; rays and projection are unchanged."""
    cam, _ = load_camera("omni-near")
    nadir_deg = np.degrees(np.arccos(np.clip(cam.pixel_rays()[..., 2], -1.0, 1.0)))
    body = nadir_deg < 60.0  # a body smaller than the 75-deg cone
    seen = cam.with_body_mask(body)
    mask = seen.valid_mask()
    assert not (mask & body).any()
    ring = (nadir_deg > 61.0) & (nadir_deg < 74.0)  # hidden by the cone, not by the body
    assert mask[ring].all() and not cam.valid_mask()[ring].any()
    beyond = ~body & ~ring & cam.valid_mask()  # the rest of the view is as before
    assert mask[beyond].all()
    np.testing.assert_array_equal(seen.pixel_rays(), cam.pixel_rays())
    assert seen.to_dict()["body_mask_deg"] == 0.0 and cam.body_mask_deg == 75.0
    with pytest.raises(ValueError, match="body mask must be"):
        cam.with_body_mask(body[:10])


@pytest.mark.parametrize("name,elev", [("omni-near", 5.0), ("omni-far", 15.0)])
def test_rim_sits_8px_inside_the_image(name, elev):
    cam, _ = load_camera(name)
    e = np.radians(elev)
    rim = np.array([[np.cos(e), 0.0, -np.sin(e)], [0.0, np.cos(e), -np.sin(e)]])
    w = cam.project(rim)
    np.testing.assert_allclose(w[0], [cam.u0 + 312.0, cam.v0], atol=1e-9)
    np.testing.assert_allclose(w[1], [cam.u0, cam.v0 + 312.0], atol=1e-9)
    mask = cam.valid_mask()
    row = int(cam.v0 + 0.5)
    assert mask[row, int(cam.u0 + 311)] and not mask[row, int(cam.u0 + 313)]
    ys, xs = np.nonzero(mask)
    assert xs.min() == 8 and xs.max() == cam.width - 9


def test_omni_validity_limits():
    cam = HyperbolicCamera.from_fov(0.04, 0.03, max_elevation_deg=5.0, body_mask_deg=75.0)

    def ray(elev_deg):
        e = np.radians(elev_deg)
        return [np.cos(e), 0.0, -np.sin(e)]

    P = np.array([ray(4.9), ray(5.1), ray(-14.9), ray(-15.1), ray(-80.0), ray(60.0), ray(89.0)])
    np.testing.assert_array_equal(
        cam.valid_rays(P), [True, False, True, False, False, False, False]
    )
    # beyond the model's limit Z/|P| <= -q3/q2 there is no image at all
    lim = np.degrees(np.arcsin(cam.xi))
    w = cam.project(np.array([ray(lim + 0.1), ray(lim - 0.1), [0.0, 0.0, 0.0]]))
    assert np.isnan(w[0]).all() and np.isfinite(w[1]).all() and np.isnan(w[2]).all()
    assert np.isnan(cam.project_jacobian(np.array([ray(lim + 0.1)]))).all()


def test_pinhole_rear_left_sees_the_road_behind_left():
    cam, mount = load_camera("rectilinear-rear-left")
    axis_point = np.asarray(mount.position_m) + 5.0 * mount.R_car_cam[:, 2]
    np.testing.assert_allclose(cam.project(car_to_cam(mount, [axis_point])), [[319.5, 239.5]])
    road_behind_left = car_to_cam(mount, [[-10.0, 3.0, 0.0], [-20.0, 2.0, 0.0]])
    assert cam.valid_rays(road_behind_left).all()
    ahead = car_to_cam(mount, [[10.0, 0.0, 0.0]])
    assert not cam.valid_rays(ahead).any() and np.isnan(cam.project(ahead)).all()
    # pitch 15 deg down, roll 0: the horizon is the row v0 - fv tan(15 deg) = 126.96
    horizon_v = cam.v0 - cam.fv * np.tan(np.radians(15.0))
    far = car_to_cam(mount, [[-1e6, 0.0, 0.0], [-1e6, 3e5, 0.0], [-1e6, 0.0, 1.2]])
    np.testing.assert_allclose(cam.project(far)[:, 1], horizon_v, atol=1e-3)
    assert (cam.project(road_behind_left)[:, 1] > horizon_v).all()
    # looking back, camera X (right) points to the car's left: outward is to the right
    w = cam.project(car_to_cam(mount, [[-15.0, 0.0, 0.0], [-15.0, 6.0, 0.0]]))
    assert w[1, 0] > w[0, 0]


def test_pinhole_formula_and_validity():
    cam = PinholeCamera(400.0, 410.0, 320.0, 240.0, skew=2.0, width=640, height=480)
    P = np.array([[1.0, 0.5, 2.0], [0.0, 0.0, -1.0], [100.0, 0.0, 1.0]])
    w = cam.project(P)
    np.testing.assert_allclose(w[0], [400 * 0.5 + 2 * 0.25 + 320, 410 * 0.25 + 240])
    assert np.isnan(w[1]).all()
    np.testing.assert_array_equal(cam.valid_rays(P), [True, False, False])


# ------------------------------------------------------------- properties
@settings(max_examples=200, deadline=None)
@given(
    name=st.sampled_from(["omni-near", "omni-far"]),
    t=st.floats(0.0, 1.0),
    az=st.floats(0.0, 2 * np.pi),
    scale=st.floats(1e-3, 1e3),
)
def test_property_omni_ray_round_trip(name, t, az, scale):
    cam = cached_camera(name)
    elev = np.radians(-(90.0 - cam.body_mask_deg) + t * (90.0 - cam.body_mask_deg + 5.0))
    d = np.array([[np.cos(elev) * np.cos(az), np.cos(elev) * np.sin(az), -np.sin(elev)]])
    back = cam.unproject(cam.project(d * scale))
    np.testing.assert_allclose(back, d, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(
    name=st.sampled_from(PRESETS),
    fu=st.floats(0.0, 1.0),
    fv=st.floats(0.0, 1.0),
)
def test_property_pixel_round_trip(name, fu, fv):
    cam = cached_camera(name)
    w = np.array([[-0.5 + fu * cam.width, -0.5 + fv * cam.height]])
    assert np.abs(cam.project(cam.unproject(w)) - w).max() < 1e-6


@settings(max_examples=200, deadline=None)
@given(
    x=st.floats(-0.7, 0.7),
    y=st.floats(-0.55, 0.55),
    depth=st.floats(0.01, 1e3),
)
def test_property_pinhole_ray_round_trip(x, y, depth):
    cam = cached_camera("rectilinear-rear-left")
    P = np.array([[x, y, 1.0]]) * depth
    back = cam.unproject(cam.project(P))
    np.testing.assert_allclose(back, P / np.linalg.norm(P), atol=1e-12)


# ------------------------------------------------------------ serialisation
@pytest.mark.parametrize(
    "cam",
    [
        HyperbolicCamera(0.04, 0.03, 1200.0, 1210.0, 321.0, 318.0, 0.5, 640, 600, 12.0, 70.0),
        PinholeCamera(420.0, 421.0, 319.5, 239.5, 0.0, 640, 480),
    ],
)
def test_to_dict_from_dict_round_trip(cam):
    d = cam.to_dict()
    assert d["model"] in ("hyperbolic", "pinhole")
    assert CameraModel.from_dict(d) == cam
    assert type(cam).from_dict(d) == cam
    assert hash(CameraModel.from_dict(d)) == hash(cam)
    assert eval(repr(cam)) == cam  # noqa: S307 - the repr is a constructor call


def test_cameras_are_immutable():
    cam = HyperbolicCamera.from_fov(0.04, 0.03)
    with pytest.raises(AttributeError, match="replace"):
        cam.fu = 10.0
    other = cam.replace(fu=10.0)
    assert other.fu == 10.0 and cam.fu != 10.0


# ------------------------------------------------------------- bad inputs
@pytest.mark.parametrize("name", ["omni-near", "rectilinear-rear-left"])
def test_bad_shapes_name_the_shape(name):
    cam, _ = load_camera(name)
    with pytest.raises(ValueError, match=r"project expects \(N, 3\) points, got shape \(4,\)"):
        cam.project(np.zeros(4))
    with pytest.raises(ValueError, match=r"got shape \(3,\)"):
        cam.project(np.zeros(3))
    with pytest.raises(ValueError, match=r"unproject expects \(N, 2\) pixels.*shape \(5, 3\)"):
        cam.unproject(np.zeros((5, 3)))
    with pytest.raises(ValueError, match=r"project_jacobian expects.*\(2, 2\)"):
        cam.project_jacobian(np.zeros((2, 2)))
    with pytest.raises(ValueError, match="dtype"):
        cam.project(np.array([["a", "b", "c"]]))


@pytest.mark.parametrize("name", ["omni-far", "rectilinear-rear-left"])
def test_nan_in_nan_out(name):
    cam, _ = load_camera(name)
    P = np.array([[np.nan, 0.0, 1.0], [0.1, 0.0, 1.0]])
    w = cam.project(P)
    assert np.isnan(w[0]).all() and np.isfinite(w[1]).all()
    assert np.isnan(cam.project_jacobian(P)[0]).all()
    assert np.isnan(cam.unproject(np.array([[np.nan, 3.0]]))).all()
    assert not cam.valid_rays(P)[0]


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"a": 0.0}, "parameter a must be > 0"),
        ({"b": -1.0}, "parameter b must be > 0"),
        ({"fu": float("nan")}, "parameter fu must be finite"),
        ({"fv": "x"}, "parameter fv must be a real number"),
        ({"u0": float("inf")}, "parameter u0 must be finite"),
        ({"width": 0}, "parameter width must be a positive integer"),
        ({"height": 640.5}, "parameter height must be a positive integer"),
        ({"width": True}, "parameter width"),
        ({"max_elevation_deg": 60.0}, "max_elevation_deg must be in"),
        ({"body_mask_deg": 95.0}, "body_mask_deg must be <"),
        ({"body_mask_deg": -1.0}, "body_mask_deg must be >= 0"),
    ],
)
def test_hyperbolic_bad_parameters(kwargs, match):
    args = {"a": 0.04, "b": 0.03, "fu": 1000.0, "fv": 1000.0, "u0": 320.0, "v0": 320.0}
    with pytest.raises(ValueError, match=match):
        HyperbolicCamera(**{**args, **kwargs})


def test_pinhole_bad_parameters_and_dicts():
    with pytest.raises(ValueError, match="parameter fu must be > 0"):
        PinholeCamera(-1.0, 400.0, 320.0, 240.0)
    with pytest.raises(ValueError, match="unknown camera model 'fisheye'"):
        CameraModel.from_dict({"model": "fisheye"})
    with pytest.raises(ValueError, match=r"unknown pinhole camera parameter\(s\) \['a'\]"):
        CameraModel.from_dict({"model": "pinhole", "fu": 1.0, "fv": 1.0, "u0": 0, "v0": 0, "a": 1})
    with pytest.raises(ValueError, match="rim_margin_px"):
        HyperbolicCamera.from_fov(0.04, 0.03, 64, 64, rim_margin_px=40)


def test_check_helpers_return_float64_copies():
    src = np.ones((2, 3), dtype=np.float32)
    out = check_points(src)
    assert out.dtype == np.float64 and out is not src
    assert check_pixels([[1, 2]]).dtype == np.float64


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.floats(1e-6, 1e6))
def test_row_norm_equals_numpy_norm_exactly(seed: int, scale: float) -> None:
    # the projections rely on it giving the very same values (results reproducible)
    P = np.random.default_rng(seed).normal(size=(257, 3)) * scale
    np.testing.assert_array_equal(row_norm(P), np.linalg.norm(P, axis=1))


def test_float32_projection_agrees_to_a_thousandth_of_a_pixel(preset):
    cam, _ = preset
    rays = cam.pixel_rays()[cam.valid_mask()][::7]  # float32 unit rays of valid pixels
    w64 = cam.project(rays.astype(np.float64))
    w32 = cam.project(rays, np.float32)
    assert w32.dtype == np.float32 and cam.project(rays).dtype == np.float64
    assert np.nanmax(np.abs(w32 - w64)) < 1e-3
    np.testing.assert_array_equal(np.isnan(w32), np.isnan(w64))
    with pytest.raises(ValueError, match="float64 or float32"):
        cam.project(rays, np.float16)
