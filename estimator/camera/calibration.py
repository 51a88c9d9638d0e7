"""Calibration of the hyperbolic omni camera (paper section 3.2).

The paper's procedure, for a camera levelled on a tripod (camera Z axis
vertical, pointing down), with features of known position on the ground and
on a vertical pole covering the field of view:

1. `fit_fov_ellipse`: the field-of-view boundary maps to an ellipse; its centre
   gives ``(u0, v0)`` and its axes the aspect ratio ``fv / fu``.
2. `fit_c1_c2`: with pixels normalised to the centre and unit aspect,
   ``u' = (u - u0) fv/fu``, ``v' = v - v0``, radial symmetry gives (eq. 11)
   ``d = sqrt(u'^2 + v'^2) = sqrt(X^2 + Y^2) / (c1 Z + c2 |P|)``,
   ``c1 = q2 / (q1 fv)``, ``c2 = q3 / (q1 fv)``, linear in c1, c2 (eq. 12):
   ``d Z c1 + d |P| c2 = sqrt(X^2 + Y^2)``.
   The algebra checks out against eq. 6 and 8: with zero skew
   ``u - u0 = fu x``, ``v - v0 = fv y``, so ``d = fv |p|`` and, by eq. 6,
   ``|p| = q1 sqrt(X^2+Y^2) / (q2 Z + q3 |P|)``; dividing by ``q1 fv`` gives eq. 11.
   Each row of eq. 12 is divided by ``|P|`` (the model does not depend on the
   scale of P) and, after a first solve, weighted by ``1/(c1 Z/|P| + c2)`` so
   that its residual is the error in d in pixels (one reweighting).
3. `refine`: non-linear least squares (``scipy.optimize.least_squares``) of the
   reprojection error over all intrinsics.

Observability: the projection depends on the mirror only through
``xi = q3/q2`` (a function of b/a) and on the focal lengths only through
``gamma_u = fu q1/q2``, ``gamma_v = fv q1/q2`` (Mei's unified model; c1 and c2
are ``1/gamma_v`` and ``xi/gamma_v``). The scale of a and b is not observable.
`refine` therefore estimates ``(xi, gamma_u, gamma_v, u0, v0[, skew_gamma])``
and keeps the mirror's ``a`` fixed (``b``, ``fu``, ``fv``, ``skew`` follow, see
`HyperbolicCamera.from_unified`).

CSV input (`calibrate_csv`): a header line, then one row per feature::

    X,Y,Z,u,v,kind
    1.20,-3.40,1.10,402.1,288.7,point
    ,,,633.2,318.9,boundary

``X, Y, Z`` [m]: the feature in the camera frame (Z down the mirror axis, so a
ground point at depth h below the viewpoint has Z = h); ``u, v`` [px]: its pixel.
The ``kind`` column is optional: ``point`` (default, also when empty) or
``boundary`` (a pixel on the field-of-view boundary: X, Y, Z are left empty
and ignored). Boundary pixels may also come in a second file (``boundary_csv``)
with columns ``u,v``; both sources are used together. Blank lines and lines
starting with ``#`` are skipped.

Errors in the input raise `CalibrationError` (a ValueError) naming the file,
the line or row, the column and the problem.
"""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np
from scipy.optimize import least_squares

from estimator.camera.models import HyperbolicCamera

MIN_POINTS = 6  # fewest correspondences calibrate() accepts (6 parameters at most)
MIN_BOUNDARY_POINTS = 6  # fewest boundary pixels for the ellipse (5 define a conic)
MIN_ELEVATION_SPREAD = 0.02  # least range of Z/|P| over the points (~1 deg at the horizon)
CSV_COLUMNS = ("X", "Y", "Z", "u", "v")


class CalibrationError(ValueError):
    """Calibration input is missing, malformed or degenerate."""


class FovEllipse(NamedTuple):
    """Field-of-view ellipse fitted to boundary pixels.

    u0, v0 [px]: centre. aspect: fv / fu. r_u, r_v [px]: ``fu rho``, ``fv rho``
    (rho the boundary's |p|). skew_ratio: skew / fu. semi_major, semi_minor
    [px] and angle_deg (major axis from the u axis towards v): the ellipse's
    axes. rms_px: RMS distance of the boundary pixels to the ellipse.
    """

    u0: float
    v0: float
    aspect: float
    r_u: float
    r_v: float
    skew_ratio: float
    semi_major: float
    semi_minor: float
    angle_deg: float
    rms_px: float


@dataclass
class CalibrationReport:
    """What `calibrate` measured.

    rms_px: RMS over points of the reprojection error's length [px] (OpenCV's
    convention); rms_axis_px: RMS over all u and v residuals [px] (= rms_px/sqrt2
    for isotropic errors); max_px: largest error [px]; residuals_px: (N, 2)
    projected minus observed pixels; errors_px: (N,) their lengths. c1, c2: the
    linear estimate of eq. 12; c1_refined, c2_refined: the same quantities of
    the refined camera (q2/(q1 fv), q3/(q1 fv)). xi: q3/q2 of the refined camera.
    """

    rms_px: float
    rms_axis_px: float
    max_px: float
    residuals_px: np.ndarray
    errors_px: np.ndarray
    c1: float
    c2: float
    c1_refined: float
    c2_refined: float
    xi: float
    n_points: int
    n_evaluations: int
    message: str
    ellipse: FovEllipse | None = None
    initial_camera: HyperbolicCamera | None = field(default=None, repr=False)

    def summary(self) -> str:
        """A few human-readable lines."""
        lines = [
            f"{self.n_points} points: reprojection RMS {self.rms_px:.3f} px "
            f"({self.rms_axis_px:.3f} px per coordinate), max {self.max_px:.3f} px",
            f"eq. 12 linear fit: c1 = {self.c1:.6g}, c2 = {self.c2:.6g} [1/px]; "
            f"refined: c1 = {self.c1_refined:.6g}, c2 = {self.c2_refined:.6g}, xi = {self.xi:.6f}",
        ]
        if self.ellipse is not None:
            e = self.ellipse
            lines.append(
                f"FOV ellipse: centre ({e.u0:.2f}, {e.v0:.2f}) px, aspect fv/fu {e.aspect:.5f}, "
                f"fit RMS {e.rms_px:.3f} px"
            )
        lines.append(f"optimiser: {self.n_evaluations} evaluations, {self.message}")
        return "\n".join(lines)


# ----------------------------------------------------------------- checking
def _row_label(i: int) -> str:
    return f"row {i}"


def _as_array(x: Any, cols: int, name: str, where: str) -> np.ndarray:
    try:
        arr = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError) as e:
        raise CalibrationError(f"{where}: {name} must be numeric: {e}") from None
    if arr.ndim != 2 or arr.shape[1] != cols:
        raise CalibrationError(f"{where}: {name} must have shape (N, {cols}), got {arr.shape}")
    return arr


def _check_finite(arr: np.ndarray, name: str, cols: str, where: str, label) -> None:
    bad = ~np.isfinite(arr)
    if bad.any():
        i, j = np.argwhere(bad)[0]
        raise CalibrationError(
            f"{where}: {label(int(i))}: {name} column '{cols[j]}' is {arr[i, j]} (not finite)"
        )


def _check_correspondences(
    world_P: Any,
    image_w: Any,
    where: str = "calibration input",
    label: Callable[[int], str] = _row_label,
) -> tuple[np.ndarray, np.ndarray]:
    P = _as_array(world_P, 3, "world_P", where)
    w = _as_array(image_w, 2, "image_w", where)
    if P.shape[0] != w.shape[0]:
        raise CalibrationError(
            f"{where}: world_P has {P.shape[0]} points but image_w has {w.shape[0]}"
        )
    if P.shape[0] < MIN_POINTS:
        raise CalibrationError(f"{where}: {P.shape[0]} points, at least {MIN_POINTS} are needed")
    _check_finite(P, "world_P", "XYZ", where, label)
    _check_finite(w, "image_w", "uv", where, label)
    n = np.linalg.norm(P, axis=1)
    if np.any(n == 0):
        raise CalibrationError(
            f"{where}: {label(int(np.argmin(n)))}: point at the viewpoint (0, 0, 0)"
        )
    zc = P[:, 2] / n
    if np.ptp(zc) < MIN_ELEVATION_SPREAD:
        raise CalibrationError(
            f"{where}: degenerate geometry: all points at (nearly) one elevation "
            f"(Z/|P| spans only {np.ptp(zc):.4f}); c1 and c2 cannot be separated: "
            "add points at other distances or heights (ground and pole)"
        )
    centred = w - w.mean(axis=0)
    sv = np.linalg.svd(centred, compute_uv=False)
    if sv[0] == 0 or sv[1] < 1e-3 * sv[0]:
        raise CalibrationError(
            f"{where}: degenerate geometry: the image points are (nearly) collinear; "
            "the centre and aspect cannot be estimated: add points at other azimuths"
        )
    return P, w


# --------------------------------------------------------------- ellipse (1)
def fit_fov_ellipse(boundary_px: Any, where: str = "boundary") -> FovEllipse:
    """Fit the field-of-view ellipse to (N, 2) boundary pixels (u, v).

    Direct least-squares conic fit constrained to an ellipse (Fitzgibbon et al.
    1999, in the numerically stable form of Halir & Flusser 1998), on
    centred and scaled coordinates. The image of the rim circle |p| = rho is
    ``{w : w - c = rho M m, |m| = 1}`` with ``M = [[fu, s], [0, fv]]``; the
    ellipse's matrix Q (``(w-c)^T Q (w-c) = 1``) factors as ``Q = U^T U`` with U
    upper triangular (Cholesky), and ``U^-1 = rho M`` gives r_u, r_v, skew.
    """
    b = _as_array(boundary_px, 2, "boundary_px", where)
    if b.shape[0] < MIN_BOUNDARY_POINTS:
        raise CalibrationError(
            f"{where}: {b.shape[0]} boundary points, at least {MIN_BOUNDARY_POINTS} are needed"
        )
    _check_finite(b, "boundary_px", "uv", where, _row_label)
    mean = b.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((b - mean) ** 2, axis=1))))
    if scale == 0:
        raise CalibrationError(f"{where}: all boundary points coincide")
    x, y = ((b - mean) / scale).T
    D1 = np.stack([x * x, x * y, y * y], axis=1)
    D2 = np.stack([x, y, np.ones_like(x)], axis=1)
    S1, S2, S3 = D1.T @ D1, D1.T @ D2, D2.T @ D2
    try:
        T = -np.linalg.solve(S3, S2.T)
    except np.linalg.LinAlgError:
        raise CalibrationError(f"{where}: degenerate boundary (collinear points)") from None
    Mred = S1 + S2 @ T
    Mred = np.stack([Mred[2] / 2.0, -Mred[1], Mred[0] / 2.0])  # C1^-1 Mred
    _, vecs = np.linalg.eig(Mred)
    vecs = np.real(vecs)
    cond = 4.0 * vecs[0] * vecs[2] - vecs[1] ** 2
    if not np.any(cond > 0):
        raise CalibrationError(f"{where}: the boundary points do not fit an ellipse")
    a1 = vecs[:, int(np.argmax(cond))]
    A, B, C, Dn, En, Fn = np.concatenate([a1, T @ a1])
    # conic in normalised coordinates: centre, then the matrix Q
    M2 = np.array([[A, B / 2.0], [B / 2.0, C]])
    cn = np.linalg.solve(M2, -0.5 * np.array([Dn, En]))
    f0 = float(cn @ M2 @ cn + Dn * cn[0] + En * cn[1] + Fn)
    Qn = M2 / -f0
    evals = np.linalg.eigvalsh(Qn)
    if not np.all(evals > 0):
        raise CalibrationError(f"{where}: the boundary points do not fit an ellipse")
    centre = mean + scale * cn
    Q = Qn / scale**2  # back to pixels
    U = np.linalg.cholesky(Q).T  # Q = U^T U, U upper triangular
    R = np.linalg.inv(U)  # = rho [[fu, s], [0, fv]]
    lam, vec = np.linalg.eigh(Q)  # ascending: major axis first
    semi = 1.0 / np.sqrt(lam)
    angle = math.degrees(math.atan2(vec[1, 0], vec[0, 0])) % 180.0
    # RMS distance: radial error of each point, in pixels along its direction
    rel = b - centre
    k = np.sqrt(np.einsum("ni,ij,nj->n", rel, Q, rel))
    dist = (k - 1.0) * np.linalg.norm(rel, axis=1) / np.where(k > 0, k, 1.0)
    return FovEllipse(
        u0=float(centre[0]),
        v0=float(centre[1]),
        aspect=float(R[1, 1] / R[0, 0]),
        r_u=float(R[0, 0]),
        r_v=float(R[1, 1]),
        skew_ratio=float(R[0, 1] / R[0, 0]),
        semi_major=float(semi[0]),
        semi_minor=float(semi[1]),
        angle_deg=angle,
        rms_px=float(np.sqrt(np.mean(dist**2))),
    )


# --------------------------------------------------------------- c1, c2 (2)
def fit_c1_c2(
    world_P: Any,
    image_w: Any,
    u0: float,
    v0: float,
    aspect: float,
    *,
    where: str = "calibration input",
) -> tuple[float, float]:
    """(c1, c2) of eq. 11 by linear least squares on eq. 12.

    world_P: (N, 3) features in the camera frame (Z down the axis) [m];
    image_w: (N, 2) their pixels; u0, v0 [px]: image centre; aspect: fv / fu.
    Returns c1 = q2/(q1 fv), c2 = q3/(q1 fv) [1/px].
    """
    P, w = _check_correspondences(world_P, image_w, where)
    if not (np.isfinite(aspect) and aspect > 0):
        raise CalibrationError(f"{where}: aspect must be a positive number, got {aspect!r}")
    n = np.linalg.norm(P, axis=1)
    zc = P[:, 2] / n  # Z / |P|
    rw = np.hypot(P[:, 0], P[:, 1]) / n  # sqrt(X^2 + Y^2) / |P|
    d = np.hypot((w[:, 0] - u0) * aspect, w[:, 1] - v0)  # eq. 11: d = sqrt(u'^2 + v'^2)
    A = np.stack([d * zc, d], axis=1)  # eq. 12, each row divided by |P|
    weights = np.ones_like(d)
    c = np.zeros(2)
    for _ in range(2):  # plain, then weighted so that residuals are errors in d [px]
        c, *_ = np.linalg.lstsq(A * weights[:, None], rw * weights, rcond=None)
        den = c[0] * zc + c[1]
        if not np.all(den > 0):
            break
        weights = 1.0 / den
    return float(c[0]), float(c[1])


# ------------------------------------------------------------------ refine (3)
def _unified_residuals(theta: np.ndarray, P: np.ndarray, w: np.ndarray, fixed: dict) -> np.ndarray:
    xi, gu, gv, u0, v0, sg = _unpack(theta, fixed)
    n = np.linalg.norm(P, axis=1)
    den = P[:, 2] + xi * n  # eq. 6 divided by q2: Z + xi |P|
    mx, my = P[:, 0] / den, P[:, 1] / den
    r = np.empty((P.shape[0], 2))
    r[:, 0] = gu * mx + sg * my + u0 - w[:, 0]  # eq. 8
    r[:, 1] = gv * my + v0 - w[:, 1]
    return r.ravel()


def _unified_jacobian(theta: np.ndarray, P: np.ndarray, w: np.ndarray, fixed: dict) -> np.ndarray:
    xi, gu, gv, u0, v0, sg = _unpack(theta, fixed)
    n = np.linalg.norm(P, axis=1)
    den = P[:, 2] + xi * n
    mx, my = P[:, 0] / den, P[:, 1] / den
    dmx, dmy = -mx * n / den, -my * n / den  # d m / d xi
    N = P.shape[0]
    cols = {
        "xi": (gu * dmx + sg * dmy, gv * dmy),
        "gamma_u": (mx, np.zeros(N)),
        "gamma_v": (np.zeros(N), my),
        "u0": (np.ones(N), np.zeros(N)),
        "v0": (np.zeros(N), np.ones(N)),
        "skew_gamma": (my, np.zeros(N)),
    }
    J = np.empty((2 * N, len(fixed["free"])))
    for k, name in enumerate(fixed["free"]):
        J[0::2, k], J[1::2, k] = cols[name]
    return J


_ALL = ("xi", "gamma_u", "gamma_v", "u0", "v0", "skew_gamma")


def _unpack(theta: np.ndarray, fixed: dict) -> list[float]:
    values = dict(fixed["values"])
    values.update(zip(fixed["free"], theta, strict=True))
    return [values[k] for k in _ALL]


def _refine(
    camera0: HyperbolicCamera,
    P: np.ndarray,
    w: np.ndarray,
    *,
    fit_centre: bool = True,
    fit_skew: bool = False,
    where: str = "calibration input",
) -> tuple[HyperbolicCamera, Any]:
    values = {
        "xi": camera0.xi,
        "gamma_u": camera0.gamma_u,
        "gamma_v": camera0.gamma_v,
        "u0": camera0.u0,
        "v0": camera0.v0,
        "skew_gamma": camera0.skew * camera0.q1 / camera0.q2,
    }
    free = ["xi", "gamma_u", "gamma_v"]
    free += ["u0", "v0"] if fit_centre else []
    free += ["skew_gamma"] if fit_skew else []
    fixed = {"values": values, "free": free}
    n = np.linalg.norm(P, axis=1)
    xi_lo = max(1e-6, float(np.max(-P[:, 2] / n)) + 1e-6)  # every point must have an image
    if xi_lo >= 1.0 - 1e-9:
        raise CalibrationError(f"{where}: a point lies straight above the viewpoint: no image")
    lo = {"xi": xi_lo, "gamma_u": 1e-9, "gamma_v": 1e-9}
    hi = {"xi": 1.0 - 1e-9}
    lower = np.array([lo.get(k, -np.inf) for k in free])
    upper = np.array([hi.get(k, np.inf) for k in free])
    x0 = np.array([values[k] for k in free])
    x0 = np.clip(x0, lower + 1e-12, upper - 1e-12)
    res = least_squares(
        _unified_residuals,
        x0,
        jac=_unified_jacobian,
        bounds=(lower, upper),
        x_scale="jac",
        args=(P, w, fixed),
        xtol=1e-12,
        ftol=1e-12,
        gtol=1e-12,
        max_nfev=200,
    )
    sv = np.linalg.svd(res.jac, compute_uv=False)
    if sv[-1] <= 1e-10 * sv[0]:
        raise CalibrationError(
            f"{where}: degenerate geometry: the intrinsics ({', '.join(free)}) are not all "
            "observable from these points"
        )
    xi, gu, gv, u0, v0, sg = _unpack(res.x, fixed)
    try:
        camera = HyperbolicCamera.from_unified(
            xi,
            gu,
            gv,
            u0,
            v0,
            sg,
            a=camera0.a,
            width=camera0.width,
            height=camera0.height,
            max_elevation_deg=camera0.max_elevation_deg,
            body_mask_deg=camera0.body_mask_deg,
        )
    except ValueError as e:
        raise CalibrationError(f"{where}: the refined camera is not valid: {e}") from None
    return camera, res


def refine(
    camera0: HyperbolicCamera,
    world_P: Any,
    image_w: Any,
    *,
    fit_centre: bool = True,
    fit_skew: bool = False,
) -> HyperbolicCamera:
    """Refine ``camera0``'s intrinsics by minimising the reprojection error.

    Estimates ``xi, gamma_u, gamma_v`` and, if ``fit_centre``, ``u0, v0`` and,
    if ``fit_skew``, the skew; keeps ``camera0.a`` (the unobservable mirror
    scale), size, max elevation and body mask. world_P (N, 3) in the camera
    frame [m], image_w (N, 2) [px].
    """
    if not isinstance(camera0, HyperbolicCamera):
        raise CalibrationError(
            f"refine needs a HyperbolicCamera as camera0, got {type(camera0).__name__}"
        )
    P, w = _check_correspondences(world_P, image_w)
    return _refine(camera0, P, w, fit_centre=fit_centre, fit_skew=fit_skew)[0]


# ---------------------------------------------------------------- calibrate
def calibrate(
    world_P: Any,
    image_w: Any,
    boundary_px: Any = None,
    *,
    width: int,
    height: int,
    max_elevation_deg: float = 5.0,
    body_mask_deg: float = 75.0,
    fit_skew: bool = False,
    mirror_a_m: float = 0.04,
    where: str = "calibration input",
    label: Callable[[int], str] = _row_label,
) -> tuple[HyperbolicCamera, CalibrationReport]:
    """Calibrate a hyperbolic camera from known features (paper section 3.2).

    world_P: (N, 3) features in the camera frame (Z down the axis) [m];
    image_w: (N, 2) their pixels [px]; boundary_px: optional (M, 2) pixels on
    the field-of-view boundary, giving the initial centre and aspect (without
    it: image centre, aspect 1). The centre is always refined from the points.
    width, height [px], max_elevation_deg, body_mask_deg [deg]: copied into
    the camera; mirror_a_m [m]: the mirror's a (unobservable scale);
    fit_skew: also estimate the skew. where, label: how errors name the input
    and a row (`calibrate_csv` passes the file name and its line numbers).
    """
    P, w = _check_correspondences(world_P, image_w, where, label)
    ellipse = None
    if boundary_px is not None:
        ellipse = fit_fov_ellipse(boundary_px, where=f"{where} (boundary)")
        u0, v0, aspect = ellipse.u0, ellipse.v0, ellipse.aspect
    else:
        u0, v0, aspect = (width - 1) / 2.0, (height - 1) / 2.0, 1.0
    c1, c2 = fit_c1_c2(P, w, u0, v0, aspect, where=where)
    n = np.linalg.norm(P, axis=1)
    xi_lo = float(np.max(-P[:, 2] / n))
    if c1 > 0 and xi_lo < c2 / c1 < 1.0:  # eq. 11: xi = c2/c1, gamma_v = 1/c1
        xi0, gv0 = c2 / c1, 1.0 / c1
    else:  # linear fit unusable: a mid-range mirror, gamma from the median radius
        xi0 = max(0.9, (xi_lo + 1.0) / 2.0)
        d = np.hypot((w[:, 0] - u0) * aspect, w[:, 1] - v0)
        m = np.hypot(P[:, 0], P[:, 1]) / (P[:, 2] + xi0 * n)
        gv0 = float(np.median(d[m > 0] / m[m > 0]))
    try:
        camera0 = HyperbolicCamera.from_unified(
            xi0,
            gv0 / aspect,
            gv0,
            u0,
            v0,
            a=mirror_a_m,
            width=width,
            height=height,
            max_elevation_deg=max_elevation_deg,
            body_mask_deg=body_mask_deg,
        )
    except ValueError as e:
        raise CalibrationError(f"{where}: {e}") from None
    camera, res = _refine(camera0, P, w, fit_centre=True, fit_skew=fit_skew, where=where)
    r = camera.project(P) - w
    err = np.linalg.norm(r, axis=1)
    report = CalibrationReport(
        rms_px=float(np.sqrt(np.mean(err**2))),
        rms_axis_px=float(np.sqrt(np.mean(r**2))),
        max_px=float(err.max()),
        residuals_px=r,
        errors_px=err,
        c1=c1,
        c2=c2,
        c1_refined=camera.q2 / (camera.q1 * camera.fv),
        c2_refined=camera.q3 / (camera.q1 * camera.fv),
        xi=camera.xi,
        n_points=int(P.shape[0]),
        n_evaluations=int(res.nfev),
        message=str(res.message),
        ellipse=ellipse,
        initial_camera=camera0,
    )
    return camera, report


def c1_c2_of(camera: HyperbolicCamera) -> tuple[float, float]:
    """eq. 11: (c1, c2) = (q2/(q1 fv), q3/(q1 fv)) of a camera [1/px]."""
    return camera.q2 / (camera.q1 * camera.fv), camera.q3 / (camera.q1 * camera.fv)


# ---------------------------------------------------------------------- CSV
def read_calibration_csv(
    points_csv: str | os.PathLike,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, list[int]]:
    """Read a calibration CSV (format in the module docstring).

    Returns world_P (N, 3), image_w (N, 2), boundary_px (M, 2) or None, and the
    file line number of each point.
    """
    path = Path(points_csv)
    where = f"calibration file '{path}'"
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise CalibrationError(f"{where}: not found") from None
    except OSError as e:
        raise CalibrationError(f"{where}: cannot read: {e.strerror or e}") from None
    numbered = [
        (i + 1, line)
        for i, line in enumerate(text.splitlines())
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not numbered:
        raise CalibrationError(f"{where}: empty (expected a header {','.join(CSV_COLUMNS)}[,kind])")
    rows = list(csv.reader([line for _, line in numbered]))
    header = [h.strip() for h in rows[0]]
    missing = [c for c in CSV_COLUMNS if c not in header]
    unknown = [h for h in header if h not in (*CSV_COLUMNS, "kind")]
    if missing or unknown:
        parts = []
        if missing:
            parts.append(f"missing column(s) {missing}")
        if unknown:
            parts.append(f"unknown column(s) {unknown}")
        raise CalibrationError(
            f"{where}: line {numbered[0][0]} (header): {'; '.join(parts)}; "
            f"expected {','.join(CSV_COLUMNS)}[,kind], got {','.join(header)}"
        )
    col = {h: k for k, h in enumerate(header)}
    pts, pix, bnd, lines = [], [], [], []
    for (lineno, _), row in zip(numbered[1:], rows[1:], strict=True):
        if len(row) != len(header):
            raise CalibrationError(
                f"{where}: line {lineno}: {len(row)} fields, the header has {len(header)}"
            )
        kind = row[col["kind"]].strip() if "kind" in col else ""
        kind = kind or "point"
        if kind not in ("point", "boundary"):
            raise CalibrationError(
                f"{where}: line {lineno}, column 'kind': unknown kind {kind!r} "
                "(expected 'point' or 'boundary')"
            )
        names = CSV_COLUMNS if kind == "point" else ("u", "v")
        values = {}
        for name in names:
            cell = row[col[name]].strip()
            try:
                x = float(cell)
            except ValueError:
                problem = "empty" if not cell else f"not a number: {cell!r}"
                raise CalibrationError(
                    f"{where}: line {lineno}, column '{name}': {problem}"
                ) from None
            if not math.isfinite(x):
                raise CalibrationError(
                    f"{where}: line {lineno}, column '{name}': {cell} (not finite)"
                )
            values[name] = x
        if kind == "point":
            pts.append([values["X"], values["Y"], values["Z"]])
            pix.append([values["u"], values["v"]])
            lines.append(lineno)
        else:
            bnd.append([values["u"], values["v"]])
    world_P = np.array(pts, dtype=np.float64).reshape(-1, 3)
    image_w = np.array(pix, dtype=np.float64).reshape(-1, 2)
    boundary = np.array(bnd, dtype=np.float64).reshape(-1, 2) if bnd else None
    return world_P, image_w, boundary, lines


def read_boundary_csv(boundary_csv: str | os.PathLike) -> np.ndarray:
    """(M, 2) boundary pixels from a CSV with columns ``u,v`` (``#`` comments allowed)."""
    path = Path(boundary_csv)
    where = f"boundary file '{path}'"
    try:
        text = path.read_text()
    except FileNotFoundError:
        raise CalibrationError(f"{where}: not found") from None
    except OSError as e:
        raise CalibrationError(f"{where}: cannot read: {e.strerror or e}") from None
    numbered = [
        (i + 1, line)
        for i, line in enumerate(text.splitlines())
        if line.strip() and not line.lstrip().startswith("#")
    ]
    if not numbered:
        raise CalibrationError(f"{where}: empty (expected a header u,v)")
    rows = list(csv.reader([line for _, line in numbered]))
    header = [h.strip() for h in rows[0]]
    if sorted(header) != ["u", "v"]:
        raise CalibrationError(
            f"{where}: line {numbered[0][0]} (header): expected columns u,v, got {','.join(header)}"
        )
    col = {h: k for k, h in enumerate(header)}
    out = []
    for (lineno, _), row in zip(numbered[1:], rows[1:], strict=True):
        if len(row) != 2:
            raise CalibrationError(f"{where}: line {lineno}: {len(row)} fields, expected 2")
        uv = []
        for name in ("u", "v"):
            cell = row[col[name]].strip()
            try:
                x = float(cell)
            except ValueError:
                problem = "empty" if not cell else f"not a number: {cell!r}"
                raise CalibrationError(
                    f"{where}: line {lineno}, column '{name}': {problem}"
                ) from None
            if not math.isfinite(x):
                raise CalibrationError(
                    f"{where}: line {lineno}, column '{name}': {cell} (not finite)"
                )
            uv.append(x)
        out.append(uv)
    return np.array(out, dtype=np.float64).reshape(-1, 2)


def calibrate_csv(
    points_csv: str | os.PathLike,
    *,
    boundary_csv: str | os.PathLike | None = None,
    width: int,
    height: int,
    max_elevation_deg: float = 5.0,
    body_mask_deg: float = 75.0,
    fit_skew: bool = False,
    mirror_a_m: float = 0.04,
) -> tuple[HyperbolicCamera, CalibrationReport]:
    """`calibrate` from a CSV file, plus an optional boundary CSV (module docstring)."""
    world_P, image_w, boundary, lines = read_calibration_csv(points_csv)
    if boundary_csv is not None:
        extra = read_boundary_csv(boundary_csv)
        boundary = extra if boundary is None else np.vstack([boundary, extra])
    return calibrate(
        world_P,
        image_w,
        boundary,
        width=width,
        height=height,
        max_elevation_deg=max_elevation_deg,
        body_mask_deg=body_mask_deg,
        fit_skew=fit_skew,
        mirror_a_m=mirror_a_m,
        where=f"calibration file '{Path(points_csv)}'",
        label=lambda i: f"line {lines[i]}",
    )
