"""H(x) = R + D K^T (eq. 3-4): Jacobian vs central differences, and vs the exact H."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from estimator.camera.files import load_camera
from estimator.camera.mount import CameraMount
from estimator.egomotion.homography import (
    dh_dx,
    homographies,
    homography,
    homography_jacobian,
    homography_parts,
    make_state,
)
from sim.camera_motion import T_world_car, Vibration, camera_pose, motion_between

DT = 1.0 / 15.0  # [s] 15 fps


def _central_diff(f, x: np.ndarray, h: np.ndarray) -> np.ndarray:
    cols = []
    for j in range(len(x)):
        e = np.zeros_like(x)
        e[j] = h[j]
        cols.append((f(x + e) - f(x - e)) / (2 * h[j]))
    return np.stack(cols)


def _random_state(rng: np.random.Generator) -> np.ndarray:
    return make_state(rng.normal(0, 15, 3), rng.normal(0, 0.3, 3), rng.normal(0, 0.02, 3))


@pytest.mark.parametrize("preset", ["omni-near", "rectilinear-rear-left"])
def test_jacobian_matches_central_differences(preset: str) -> None:
    _, mount = load_camera(preset)
    rng = np.random.default_rng(0)
    for _ in range(5):
        x = _random_state(rng)
        J = homography_jacobian(x, mount.K0, DT)
        h = np.r_[np.full(3, 1e-3), np.full(3, 1e-5), np.full(3, 1e-6)]
        J_fd = _central_diff(lambda y: homography(y, mount.K0, DT), x, h)
        # H is at most quadratic in x: central differences are exact up to rounding
        assert np.max(np.abs(J - J_fd)) <= 1e-7 * np.max(np.abs(J))
        assert np.allclose(dh_dx(x, mount.K0, DT), J.reshape(9, 9).T)


_finite = st.floats(-1.0, 1.0, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(_finite, min_size=9, max_size=9), st.floats(0.01, 0.2))
def test_jacobian_property(u: list[float], dt: float) -> None:
    """Any state (|V| < 30 m/s, |W| < 0.5 rad/s, |A| < 3 deg), any dt: dH/dx = differences."""
    x = np.asarray(u) * np.r_[np.full(3, 30.0), np.full(3, 0.5), np.full(3, 0.05)]
    K0 = np.array([0.1, -0.2, 0.9]) / 1.2
    J = homography_jacobian(x, K0, dt)
    h = np.r_[np.full(3, 1e-3), np.full(3, 1e-5), np.full(3, 1e-6)]
    J_fd = _central_diff(lambda y: homography(y, K0, dt), x, h)
    assert np.max(np.abs(J - J_fd)) <= 1e-7 * max(np.max(np.abs(J)), 1e-3)


def test_small_angle_parts_at_zero() -> None:
    K0 = np.array([0.0, 0.0, 1 / 1.95])
    R, D, K = homography_parts(make_state([0, -25, 0], [0, 0, 0], [0, 0, 0]), K0, DT)
    assert np.allclose(R, np.eye(3))
    assert np.allclose(D, [0, 25 * DT, 0])  # D = -V dt: the scene moves opposite to the camera
    assert np.allclose(K, K0)


def _pose(mount: CameraMount, vib: Vibration, t: float, v: float, yaw_rate: float):
    yaw = yaw_rate * t
    x, y = v / yaw_rate * np.sin(yaw), v / yaw_rate * (1 - np.cos(yaw))
    return camera_pose(T_world_car(x, y, yaw), mount, vib, t)


@pytest.mark.parametrize("preset", ["omni-near", "omni-far", "rectilinear-rear-left"])
def test_first_order_H_matches_exact_motion(preset: str) -> None:
    """25 m/s, 0.2 rad/s yaw, 0.5 deg vibration at 15 fps: the sign of D is settled here.

    Road pixels mapped by the small-angle H and by the exact H of
    sim.camera_motion.motion_between agree to a fraction of a pixel; with D of the
    opposite sign (Table 1) they are tens of pixels apart.
    """
    camera, mount = load_camera(preset)
    vib = Vibration(0.5, 2.0, 0.3, 1.1)
    a, b = _pose(mount, vib, 0.37, 25.0, 0.2), _pose(mount, vib, 0.37 + DT, 25.0, 0.2)
    ms = motion_between(a, b, DT)
    assert np.linalg.norm(ms.A_rad) > np.radians(0.3)
    x = make_state(ms.V_mps, ms.W_rps, ms.A_rad)
    rng = np.random.default_rng(1)
    w = np.column_stack([rng.uniform(0, camera.width, 4000), rng.uniform(0, camera.height, 4000)])
    rays = camera.unproject(w)
    K_a = (np.eye(3) - np.cross(np.eye(3), ms.A_rad)) @ mount.K0
    road = camera.valid_rays(rays) & (rays @ K_a > 0) & (1.0 / (rays @ mount.K0) < 40.0)
    rays = rays[road]
    w_exact = camera.project(rays @ ms.H.T)
    w_first = camera.project(rays @ homography(x, mount.K0, DT).T)
    ok = camera.in_image(w_exact)
    err = np.linalg.norm(w_first - w_exact, axis=1)[ok]
    assert ok.sum() > 500
    assert np.max(err) < 0.25, f"max {np.max(err):.3f} px"
    x_flip = make_state(-ms.V_mps, ms.W_rps, ms.A_rad)  # Table 1's sign of D
    err_flip = np.linalg.norm(
        camera.project(rays @ homography(x_flip, mount.K0, DT).T) - w_exact, axis=1
    )[ok]
    assert np.nanmedian(err_flip) > 5.0  # NaN: mapped behind the camera


def test_error_is_second_order() -> None:
    """Halving dt and the vibration amplitude divides the H error by ~4."""
    mount = CameraMount()
    errs = []
    for s in (1.0, 0.5, 0.25):
        vib = Vibration(0.5 * s, 2.0, 0.3, 1.1)
        a, b = _pose(mount, vib, 0.37, 25.0, 0.2), _pose(mount, vib, 0.37 + DT * s, 25.0, 0.2)
        ms = motion_between(a, b, DT * s)
        H = homography(make_state(ms.V_mps, ms.W_rps, ms.A_rad), mount.K0, DT * s)
        errs.append(np.max(np.abs(H - ms.H)))
    assert errs[0] / errs[1] > 3.0 and errs[1] / errs[2] > 3.0


def test_bad_state_shape() -> None:
    from estimator.egomotion.homography import check_state

    with pytest.raises(ValueError, match=r"shape \(9,\).*\(6,\)"):
        check_state(np.zeros(6))
    with pytest.raises(ValueError, match="finite"):
        check_state(np.full(9, np.nan))


def test_batched_homographies_are_bitwise_the_single_ones() -> None:
    """`homographies` (the grid search's batched form) gives exactly `homography` per
    state: random grids around random states, zero and -0 components included."""
    rng = np.random.default_rng(0)
    for i in range(300):
        x0 = rng.normal(size=9) * rng.choice([1e-3, 1.0, 30.0])
        X = x0 + rng.normal(size=(int(rng.integers(1, 60)), 9)) * rng.choice([0, 1e-3, 1], size=9)
        X[:, rng.integers(0, 9)] = 0.0 if i % 2 else -0.0
        K0, dt = rng.normal(size=3), float(rng.random() * 0.1)
        single = np.stack([homography(x, K0, dt) for x in X])
        assert homographies(X, K0, dt).tobytes() == single.tobytes()
