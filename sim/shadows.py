"""How brightly the road plane is lit around the vehicles: their shadows on it.

A vehicle hides the sun from the ground in its shadow (the outlines of the template's
convex solids cast along the sunlight onto z = 0) and part of the sky under and around it
(ambient occlusion: the same solids cast along `OCCLUSION_DIRS` cosine-weighted directions
of the sky, once per vehicle size, in the vehicle's frame: `sky_hidden_table`). The plane's
irradiance there, as a fraction of the open road's, is

    light = (AMBIENT * sky_visible + SUN_DIFFUSE * cos(zenith) * sun_visible)
            / (AMBIENT + SUN_DIFFUSE * cos(zenith))

with the scene's sun and ambient light (`sim.coded_scene`, pyrender's diffuse term). Real
vehicles always show this dark contact where they meet the road; an image without it
shows a vehicle's lower edge against the road with no contrast. The camera's own car
casts none (its shadow would be fixed in the image, as its body is).

What hides the sun is drawn into a grid of `CELL_M` cells, what hides the sky into one of
`OCCLUSION_CELL_M` (each vehicle's table turned into place; where several hide the sky,
the shares they leave visible multiply, as if the directions they hide were independent),
both `HALF_M` each way around the camera; the plane's kernel (`sim.ground`) reads them
bilinearly, only on the `NEAR_CELL_M` blocks near a vehicle. Beyond the grids the road is
fully lit.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence

import cv2
import numpy as np

from sim.coded_scene import AMBIENT, SUN_DIFFUSE, SUN_TOWARDS
from sim.ground import LightMap
from sim.highway import VehicleState
from sim.scene import vehicle_solids

CELL_M = 0.05  # [m] light grid cell (sun shadows), 0.02..0.1
HALF_M = 40.0  # [m] the grid reaches this far from the camera along x and y
OCCLUSION_CELL_M = 0.1  # [m] cell of the ambient occlusion (sky hidden), 0.05..0.2
# [m] the sky a vehicle hides is drawn this far around its footprint (there 0.012 of the
# sky beside a car, 0.006 behind: under half a grey level), 2..6
OCCLUSION_REACH_M = 4.0
OCCLUSION_DIRS = 1024  # [-] cosine-weighted directions of the sky per vehicle size, 256..4096
_TABLE_SUBCELLS = 4  # [-] the table is drawn on cells this many times finer, then averaged
# [m] sizes are rounded to this for the table (the share hidden changes by < 0.003)
_TABLE_SIZE_STEP_M = 0.02
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
    solids = vehicle_solids(others)  # (M, S, K, 3)
    # sun: every solid's corners slid along the sunlight down to the road, their outline
    cast = solids[..., :2] - (solids[..., 2:3] / _SUN[2]) * _SUN[:2]  # (M, S, K, 2)
    n = int(round(2.0 * half_m / CELL_M))
    sun = _fill(cast.reshape(-1, *cast.shape[2:]), origin, CELL_M, (n, n), hull_first=True)
    sky = _sky_hidden(others, origin, half_m)
    # the blocks where either grid may be nonzero (the sky's exactly, each shadow's
    # bounds and a cell of antialiasing), and a block around: a bilinear read reaches
    # one cell
    b = int(round(2.0 * half_m / NEAR_CELL_M))
    near = (cv2.resize(sky, (b, b), interpolation=cv2.INTER_AREA) > 0).astype(np.uint8)
    for shade in cast.reshape(len(others), -1, 2):
        lo = np.floor((shade.min(axis=0) - CELL_M - origin) / NEAR_CELL_M).astype(int)
        hi = np.floor((shade.max(axis=0) + CELL_M - origin) / NEAR_CELL_M).astype(int) + 1
        (i0, j0), (i1, j1) = np.clip(lo, 0, b), np.clip(hi, 0, b)
        near[j0:j1, i0:i1] = 1
    near = cv2.dilate(near, np.ones((3, 3), np.uint8))
    return LightMap(sun, CELL_M, sky, OCCLUSION_CELL_M, half_m, near, NEAR_CELL_M, LIGHT_WEIGHTS)


@functools.lru_cache(maxsize=256)
def _sky_hidden_table(length_m: float, width_m: float, height_m: float) -> np.ndarray:
    """`sky_hidden_table`'s table for a vehicle of this size [m] (read-only, cached)."""
    v = VehicleState(0, 0.0, 0.0, 0.0, 0.0, length_m, width_m, height_m, 0.0, False, False)
    solids = vehicle_solids([v])[0]  # (S, K, 3) in the vehicle's frame
    cell, reach = OCCLUSION_CELL_M / _TABLE_SUBCELLS, OCCLUSION_REACH_M
    origin = -np.array([length_m / 2 + reach, width_m / 2 + reach])
    n = np.ceil(-2.0 * origin / OCCLUSION_CELL_M - 1e-6).astype(int) * _TABLE_SUBCELLS
    # cosine-weighted directions (Malley: a sunflower on the unit disk lifted onto the
    # hemisphere), each 1 / OCCLUSION_DIRS of the sky's light on the plane
    k = np.arange(OCCLUSION_DIRS)
    r, phi = np.sqrt((k + 0.5) / OCCLUSION_DIRS), k * np.pi * (3.0 - np.sqrt(5.0))
    dirs = np.column_stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(1.0 - r * r)])
    hidden = np.zeros((n[1], n[0]), np.float32)
    for d in dirs:
        # the ground points whose ray along d meets a solid: its corners slid along d
        pts = solids[..., :2] - (solids[..., 2:3] / d[2]) * d[:2]  # (S, K, 2)
        hidden += _fill(pts, origin, cell, n, hull_first=True, line=cv2.LINE_8)
    hidden *= np.float32(1.0 / (255 * OCCLUSION_DIRS))
    hidden = cv2.resize(hidden, tuple(n // _TABLE_SUBCELLS), interpolation=cv2.INTER_AREA)
    hidden.flags.writeable = False
    return hidden


def sky_hidden_table(v: VehicleState) -> tuple[np.ndarray, np.ndarray]:
    """The share of the sky's light (cosine-weighted, 0..1) that vehicle v hides from the
    road plane around it, in its own frame (x forward, y left, origin at the footprint's
    centre): (ny, nx) float32 of `OCCLUSION_CELL_M` cells, `OCCLUSION_REACH_M` beyond the
    footprint each way, and the (2,) [m] (x, y) of the table's corner (cell (0, 0)'s
    lower-left). Computed once per vehicle size (to `_TABLE_SIZE_STEP_M`)."""
    dims = tuple(
        round(x / _TABLE_SIZE_STEP_M) * _TABLE_SIZE_STEP_M
        for x in (v.length_m, v.width_m, v.height_m)
    )
    return _sky_hidden_table(*dims), -np.array([dims[0] / 2, dims[1] / 2]) - OCCLUSION_REACH_M


def _sky_hidden(vehicles: Sequence[VehicleState], origin: np.ndarray, half_m: float) -> np.ndarray:
    """(N, N) float32 share of the sky hidden on the grid of `OCCLUSION_CELL_M` cells from
    origin (2,) [m, world]: each vehicle's table turned into place; the visible shares
    multiply."""
    cell = OCCLUSION_CELL_M
    n = int(round(2.0 * half_m / cell))
    visible = np.ones((n, n), np.float32)
    for v in vehicles:
        table, corner = sky_hidden_table(v)
        c, s = np.cos(v.yaw_rad), np.sin(v.yaw_rad)
        rot_t = np.array([[c, s], [-s, c]])  # world (x, y) -> the vehicle's frame
        th, tw = table.shape
        world = (corner + np.array([[0, 0], [tw, 0], [tw, th], [0, th]]) * cell) @ rot_t
        world += (v.x_m, v.y_m)  # (4, 2) [m] the table's corners
        lo = np.clip(np.floor((world.min(axis=0) - origin) / cell).astype(int) - 1, 0, n)
        hi = np.clip(np.ceil((world.max(axis=0) - origin) / cell).astype(int) + 1, 0, n)
        if np.any(hi <= lo):
            continue
        # grid cell (i, j) of the window -> table cell coordinates (cell centres at +0.5)
        shift = (origin + (lo + 0.5) * cell - (v.x_m, v.y_m)) / cell
        to_table = np.column_stack([rot_t, rot_t @ shift - corner / cell - 0.5])
        part = cv2.warpAffine(
            table,
            to_table,
            (int(hi[0] - lo[0]), int(hi[1] - lo[1])),
            flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=0.0,
        )
        visible[lo[1] : hi[1], lo[0] : hi[0]] *= 1.0 - part
    return 1.0 - visible


def _fill(
    polygons: np.ndarray,
    origin: np.ndarray,
    cell_m: float,
    size: np.ndarray,
    hull_first: bool,
    line: int = cv2.LINE_AA,
) -> np.ndarray:
    """(ny, nx) uint8 grid of cell_m [m] from origin (2,) [m], size (nx, ny) cells, 255
    inside the convex polygons (M, K, 2) [m] (their convex hulls if hull_first), drawn
    with OpenCV's line type (antialiased by default)."""
    grid = np.zeros((int(size[1]), int(size[0])), np.uint8)
    one = 1 << _SUBPIXEL_BITS
    for pts in polygons:
        fixed = np.round((pts - origin) * (one / cell_m) - 0.5 * one).astype(np.int32)
        if hull_first:
            fixed = cv2.convexHull(fixed)
        cv2.fillConvexPoly(grid, fixed, 255, line, _SUBPIXEL_BITS)
    return grid
