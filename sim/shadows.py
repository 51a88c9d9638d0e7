"""How brightly the road plane is lit around the vehicles: their shadows on it.

A vehicle hides the sun from the ground in its shadow (the outlines of the template's
convex solids cast along the sunlight onto z = 0) and part of the sky under and around it
(ambient occlusion: the footprint blurred over `OCCLUSION_SIGMA_M`). The plane's
irradiance there, as a fraction of the open road's, is

    light = (AMBIENT * sky_visible + SUN_DIFFUSE * cos(zenith) * sun_visible)
            / (AMBIENT + SUN_DIFFUSE * cos(zenith))

with the scene's sun and ambient light (`sim.coded_scene`, pyrender's diffuse term). Real
vehicles always show this dark contact where they meet the road; an image without it
shows a vehicle's lower edge against the road with no contrast. The camera's own car
casts none (its shadow would be fixed in the image, as its body is).

What hides the sun is drawn into a grid of `CELL_M` cells, what hides the sky into one of
`OCCLUSION_CELL_M`, both `HALF_M` each way around the camera; the plane's kernel
(`sim.ground`) reads them bilinearly, only on the `NEAR_CELL_M` blocks near a vehicle.
Beyond the grids the road is fully lit.
"""

from __future__ import annotations

from collections.abc import Sequence

import cv2
import numpy as np

from sim.coded_scene import AMBIENT, SUN_DIFFUSE, SUN_TOWARDS
from sim.ground import LightMap
from sim.highway import VehicleState
from sim.scene import vehicle_solids

CELL_M = 0.05  # [m] light grid cell (sun shadows), 0.02..0.1
HALF_M = 40.0  # [m] the grid reaches this far from the camera along x and y
OCCLUSION_CELL_M = 0.1  # [m] cell of the ambient occlusion, blurred then resampled
OCCLUSION_SIGMA_M = 0.3  # [m] spread of the sky a vehicle hides around its footprint
NEAR_CELL_M = 1.0  # [m] blocks of the grids that the kernel skips where both are 0
_SUBPIXEL_BITS = 4  # cv2 fixed-point fraction bits of the polygons' corners

_SUN = -SUN_TOWARDS / np.linalg.norm(SUN_TOWARDS)  # towards the sun (world)
SUN_DIRECT = float(SUN_DIFFUSE * _SUN[2])  # [-] the sun's part of the road's irradiance
# what hiding all the sun, all the sky takes off the open road's light [-]
LIGHT_WEIGHTS = np.array([SUN_DIRECT, AMBIENT]) / (AMBIENT + SUN_DIRECT)


def light(sun_hidden: np.ndarray, sky_hidden: np.ndarray) -> np.ndarray:
    """The plane's irradiance as a fraction of the open road's [-], from the parts of the
    sun and of the sky hidden (0..1, any shape)."""
    return (AMBIENT * (1.0 - sky_hidden) + SUN_DIRECT * (1.0 - sun_hidden)) / (AMBIENT + SUN_DIRECT)


def cast_shadows(
    vehicles: Sequence[VehicleState], camera_xy: np.ndarray, half_m: float = HALF_M
) -> LightMap:
    """The light map of the vehicles (all but the camera's own car) around camera_xy (2,)
    [m, world]."""
    others = [
        v
        for v in vehicles
        if not v.is_ego
        and abs(v.x_m - camera_xy[0]) < half_m + 10.0
        and abs(v.y_m - camera_xy[1]) < half_m + 10.0
    ]
    if not others:
        return LightMap.lit()
    origin = np.asarray(camera_xy, float) - half_m  # world (x, y) of the grids' corner
    solids, foot = vehicle_solids(others)  # (M, S, K, 3), (M, 4, 2)
    # sun: every solid's corners slid along the sunlight down to the road, their outline
    cast = solids[..., :2] - (solids[..., 2:3] / _SUN[2]) * _SUN[:2]  # (M, S, K, 2)
    sun = _fill(cast.reshape(-1, *cast.shape[2:]), origin, CELL_M, half_m, hull_first=True)
    # sky: the footprints, blurred
    occ = _fill(foot, origin, OCCLUSION_CELL_M, half_m, hull_first=False)
    sigma = OCCLUSION_SIGMA_M / OCCLUSION_CELL_M
    sky = cv2.GaussianBlur(occ.astype(np.float32) * np.float32(1 / 255), (0, 0), sigma)
    # the blocks the grids may be nonzero on: each vehicle's shadow and footprint, grown
    # by the blur's reach (OpenCV's kernel: 4 sigma) and a cell of antialiasing
    b = int(round(2.0 * half_m / NEAR_CELL_M))
    near = np.zeros((b, b), np.uint8)
    grow = 4.0 * OCCLUSION_SIGMA_M + 2.0 * OCCLUSION_CELL_M
    for shade, rect in zip(cast.reshape(len(foot), -1, 2), foot, strict=True):
        lo = np.minimum(shade.min(axis=0), rect.min(axis=0) - grow) - origin
        hi = np.maximum(shade.max(axis=0), rect.max(axis=0) + grow) - origin
        i0, j0 = np.clip(np.floor(lo / NEAR_CELL_M).astype(int) - 1, 0, b)
        i1, j1 = np.clip(np.floor(hi / NEAR_CELL_M).astype(int) + 2, 0, b)
        near[j0:j1, i0:i1] = 1  # and a block around: a bilinear read reaches one cell
    return LightMap(sun, CELL_M, sky, OCCLUSION_CELL_M, half_m, near, NEAR_CELL_M, LIGHT_WEIGHTS)


def _fill(
    polygons: np.ndarray, origin: np.ndarray, cell_m: float, half_m: float, hull_first: bool
) -> np.ndarray:
    """(N, N) uint8 grid of cell_m [m] from origin (2,) [m], 255 inside the convex
    polygons (M, K, 2) [m] (their convex hulls if hull_first), antialiased."""
    n = int(round(2.0 * half_m / cell_m))
    grid = np.zeros((n, n), np.uint8)
    one = 1 << _SUBPIXEL_BITS
    for pts in polygons:
        fixed = np.round((pts - origin) * (one / cell_m) - 0.5 * one).astype(np.int32)
        if hull_first:
            fixed = cv2.convexHull(fixed)
        cv2.fillConvexPoly(grid, fixed, 255, cv2.LINE_AA, _SUBPIXEL_BITS)
    return grid
