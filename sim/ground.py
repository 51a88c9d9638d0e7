"""The road plane rendered analytically: every camera pixel's ray meets z = 0 exactly.

The road, its markings and the grass beside it are one plane (docs/CONVENTIONS.md).
Instead of rasterising that plane into cube faces and resampling the faces (a texture
pattern on a grid fixed to the camera, which pulls the image motion towards zero), each
pixel's ray is intersected with the plane and the plane's appearance is integrated over
the pixel's own footprint there:

- The footprint is the image of a Gaussian pixel response (`PIXEL_SIGMA_PX`) through the
  ray-plane map, an ellipse on the plane [m] (`_footprints`).
- As GPUs filter anisotropically, the ellipse is covered by up to `MAX_PROBES` probes
  along its major axis, Gaussian weighted; each probe reads mip levels as wide as the
  minor axis (trilinear: two levels, blended). Where the footprint is longer than
  MAX_PROBES probes cover at that width (nearly all of an omni camera's road), the
  textures (asphalt, grass) are read wider, as wide as the probes' spacing, so that
  their fine grain does not alias; the coverage (where markings and the road's edge
  are: a few hard edges, not a grain) is always read at the minor axis, so that a
  marking keeps its sharp edges across the line of sight (docs/DESIGN.md). Where the
  coverage changes from a probe to its neighbour, an edge lies in the probe's cell
  (halfway to each neighbour) and the probe takes the coverage's mean over the cell
  (`COVER_SUBSAMPLES` samples along it): a dash's end moves smoothly through the
  footprint instead of jumping from probe to probe.
- Textures (asphalt, grass) are periodic tiles in world metres (`MipTexture`). Where
  the road and its markings are is a world raster of coverage (`CoverageMap`): a fine
  window of tiles around the camera and a coarse map of the whole area, with mips; a
  pixel reads the fine window wherever its footprint's minor axis is within the
  window's coarsest level (the coarse map's 20-cm cells would blur a marking there).

Everything is a function of the world point and the pixel's footprint, never of a grid
fixed to the camera, so the road moves in the images exactly as the plane-induced
homography says (`scenarios.motion_fidelity` measures it). The per-frame work, a loop
over every probe, is one compiled kernel (`_shade`, numba, parallel over pixels).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from estimator.camera.models import CameraModel

PIXEL_SIGMA_PX = 0.5  # [px] std of a camera pixel's Gaussian response, 0.3..1
MAX_PROBES = 8  # [-] most probes along a footprint's major axis, 1..32
COVER_SUBSAMPLES = 8  # [-] coverage samples across a probe's cell where an edge lies in it, 1..32
COVER_EDGE = 1e-3  # [-] coverage change to a neighbour probe that marks an edge, 0..0.1
OUTSIDE_VIEW_PROBES = 2  # [-] most probes of pixels outside the valid view (shown only), 1..8
FINE_CELL_M = 0.025  # [m] cell of the fine coverage raster, 0.01..0.05
FINE_LEVELS = 4  # [-] mip levels of the fine raster (2.5, 5, 10, 20 cm), 1..6
TILE_CELLS = 512  # [cells] side of a fine coverage tile (12.8 m at 2.5 cm), 64..2048
WINDOW_TILES = 7  # [tiles] side of the fine window around the camera (odd), 3..15
COARSE_CELL_M = 0.2  # [m] cell of the whole area's coverage raster, 0.05..1
COARSE_SUPERSAMPLE = 4  # [-] the coarse raster averages this many^2 point samples, 1..8
MAX_RANGE_M = 400.0  # [m] ground farther along the ray is not drawn (sky)
DISPLAY_GAMMA = 2.2  # [-] pixel value = 255 * linear radiance ** (1 / gamma), as pyrender


# the kernel's floating-point licences: fused multiply-adds, reciprocals, reassociation and
# fast pow (rounding-level changes only; no assumption that values are finite)
_FAST = {"contract", "arcp", "afn", "reassoc"}


def srgb_to_linear(image: np.ndarray) -> np.ndarray:
    """float32 linear values [0, 1] of sRGB-encoded uint8 values (IEC 61966-2-1)."""
    c = np.asarray(image, np.float32) / np.float32(255.0)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4).astype(np.float32)


def _mips(level0: np.ndarray, n_levels: int) -> list[np.ndarray]:
    """level0 (R, C, K) and its box-filtered halvings, n_levels in all at most."""
    levels = [level0]
    while len(levels) < n_levels and min(levels[-1].shape[:2]) >= 2:
        lv = levels[-1]
        half = cv2.resize(lv, (lv.shape[1] // 2, lv.shape[0] // 2), interpolation=cv2.INTER_AREA)
        levels.append(half.reshape(half.shape[0], half.shape[1], lv.shape[2]))
    return levels


class MipAtlas:
    """An image on the plane (R, C, K) and its mips, packed side by side in one atlas.

    Level k has cells of ``cell_m * 2**k`` [m]; its cell (0, 0) is at atlas column
    ``col[k]`` and row ``row0``, with its corner at the plane point ``origin_xy`` [m].
    Periodic images (textures, ``period[k]`` cells) are padded with 2 wrapped cells on
    the right and bottom; others (coverage rasters, ``period[k] = 0``) are framed by one
    empty cell, so that reads outside them give 0.
    """

    def __init__(self, levels: list, cell_m: float, periodic: bool, origin_xy=(0.0, 0.0)):
        K = levels[0].shape[2]
        pad = 0 if periodic else 1
        if periodic:
            padded = [cv2.copyMakeBorder(lv, 0, 2, 0, 2, cv2.BORDER_WRAP) for lv in levels]
        else:
            padded = [cv2.copyMakeBorder(lv, 1, 1, 1, 1, cv2.BORDER_CONSTANT, 0) for lv in levels]
        padded = [p.reshape(p.shape[0], p.shape[1], K) for p in padded]
        widths = [p.shape[1] for p in padded]
        self.col = (np.cumsum([0, *widths[:-1]]) + pad).astype(np.float64)  # (L,)
        self.row0 = float(pad)
        self.atlas = np.zeros((padded[0].shape[0], sum(widths), K), levels[0].dtype)
        for p, c in zip(padded, self.col, strict=True):
            self.atlas[: p.shape[0], int(c) - pad : int(c) - pad + p.shape[1]] = p
        self.cell_m = float(cell_m)
        self.per_m = 1.0 / (self.cell_m * 2.0 ** np.arange(len(levels)))  # (L,) cells per m
        sizes = np.array([lv.shape[1] for lv in levels], np.float64)
        self.period = sizes if periodic else np.zeros(len(levels))
        per = self.period
        self.inv_period = np.divide(1.0, per, out=np.zeros(len(levels)), where=per > 0)
        self.origin_xy = np.asarray(origin_xy, np.float64)

    @property
    def n_levels(self) -> int:
        return len(self.col)

    def put(self, level: int, row: int, col: int, block: np.ndarray) -> None:
        """Write block (r, c, K) at cell (row, col) of a level."""
        c0, r0 = int(self.col[level]) + col, int(self.row0) + row
        self.atlas[r0 : r0 + block.shape[0], c0 : c0 + block.shape[1]] = block

    def levels(self, blur_m: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(P,) int64 mip level and (P,) float64 blend towards the next one: the level
        whose cells are twice a blur std (P,) [m] (trilinear filtering)."""
        with np.errstate(divide="ignore"):
            lam = np.log2(np.maximum(2.0 * np.asarray(blur_m) / self.cell_m, 1e-12))
        lam = np.clip(lam, 0.0, self.n_levels - 1)
        lo = np.minimum(np.floor(lam), max(self.n_levels - 2, 0))
        return lo.astype(np.int64), np.clip(lam - lo, 0.0, 1.0)


class MipTexture(MipAtlas):
    """A periodic texture tile (N, N, 3), N a power of two, laid on the plane with period
    tile_m [m].

    srgb: the image is sRGB-encoded uint8 and the atlas holds linear values [0, 1]
    (filtered in linear space); otherwise the image's values as float32.
    """

    def __init__(self, image: np.ndarray, tile_m: float, srgb: bool = False) -> None:
        image = np.asarray(image)
        if image.ndim != 3 or image.shape[0] != image.shape[1] or image.shape[2] != 3:
            raise ValueError(f"texture must be (N, N, 3), got {image.shape}")
        n = image.shape[0]
        if n & (n - 1):
            raise ValueError(f"texture side must be a power of two, got {n}")
        level0 = srgb_to_linear(image) if srgb else image.astype(np.float32)
        super().__init__(_mips(level0, 64), float(tile_m) / n, periodic=True)
        self.tile_m = float(tile_m)


def rasterize_coverage(
    polygons: list[np.ndarray], origin_xy: tuple[float, float], cell_m: float, shape: tuple
) -> np.ndarray:
    """(rows, cols) uint8 raster, 255 where a cell's centre lies in one of the convex
    polygons (each (K, 2) world [m]); cell (0, 0) has its corner at origin_xy."""
    out = np.zeros(shape, np.uint8)
    shift = 8
    scale = float(1 << shift)
    ox, oy = origin_xy
    rows, cols = shape
    for poly in polygons:
        c = (poly - (ox, oy)) / cell_m - 0.5  # centre-index coordinates
        if c[:, 0].max() < -1 or c[:, 1].max() < -1 or c[:, 0].min() > cols or c[:, 1].min() > rows:
            continue
        cv2.fillConvexPoly(out, np.round(c * scale).astype(np.int32), 255, cv2.LINE_8, shift)
    return out


class CoverageMap:
    """Where the road and its markings are on the plane: convex polygons (world, [m])
    rasterised at FINE_CELL_M in square tiles, built once each and kept (the window of
    tiles around the camera is one framed `MipAtlas`), and at COARSE_CELL_M over the area.

    A tile's cells depend on the world only, so a render resumed at any frame draws the
    same road, and a map of another window of the same world (a window that moved with
    the camera, whose fine tiles all lie well inside it) can take over the tiles built
    (``tiles_from``).
    """

    def __init__(
        self,
        road: list[np.ndarray],
        markings: list[np.ndarray],
        area_xy: tuple,
        tiles_from: CoverageMap | None = None,
    ) -> None:
        self.road, self.markings = road, markings
        self._boxes = {"road": _bboxes(road), "markings": _bboxes(markings)}
        xmin, xmax, ymin, ymax = area_xy
        cell = COARSE_CELL_M
        ox, oy = np.floor(xmin / cell) * cell, np.floor(ymin / cell) * cell
        cols = int(np.ceil((xmax - ox) / cell))
        rows = int(np.ceil((ymax - oy) / cell))
        ss = COARSE_SUPERSAMPLE
        level0 = np.zeros((rows, cols, 2), np.uint8)
        step = max(1, 2048 // ss)  # rasterised in chunks of step x step coarse cells
        for r in range(0, rows, step):
            for c in range(0, cols, step):
                h, w = min(step, rows - r), min(step, cols - c)
                o = (ox + c * cell, oy + r * cell)
                fine = self._rasterize(o, cell / ss, h * ss, w * ss)
                level0[r : r + h, c : c + w] = cv2.resize(fine, (w, h), cv2.INTER_AREA)
        self.coarse = MipAtlas(_mips(level0, 16), cell, periodic=False, origin_xy=(ox, oy))
        n = TILE_CELLS * WINDOW_TILES
        self.fine = MipAtlas(
            _mips(np.zeros((n, n, 2), np.uint8), FINE_LEVELS), FINE_CELL_M, periodic=False
        )
        self._window: tuple[int, int] | None = None
        self._tiles: OrderedDict[tuple[int, int], list[np.ndarray]] = (
            tiles_from._tiles if tiles_from is not None else OrderedDict()
        )

    @property
    def tile_m(self) -> float:
        return TILE_CELLS * FINE_CELL_M

    @property
    def reach_m(self) -> float:
        """[m] the fine window holds at least this much plane around the camera."""
        return (WINDOW_TILES // 2) * self.tile_m

    def _rasterize(self, origin, cell_m: float, rows: int, cols: int) -> np.ndarray:
        """(rows, cols, 2) uint8 point-sampled (road, marking) coverage."""
        out = np.zeros((rows, cols, 2), np.uint8)
        box = (origin[0], origin[0] + cols * cell_m, origin[1], origin[1] + rows * cell_m)
        for ch, name in enumerate(("road", "markings")):
            polys = getattr(self, name)
            lo, hi = self._boxes[name]
            near = (
                (lo[:, 0] <= box[1])
                & (hi[:, 0] >= box[0])
                & (lo[:, 1] <= box[3])
                & (hi[:, 1] >= box[2])
            )
            out[..., ch] = rasterize_coverage(
                [p for p, k in zip(polys, near, strict=True) if k], origin, cell_m, (rows, cols)
            )
        return out

    def _tile(self, i: int, j: int) -> list[np.ndarray]:
        key = (i, j)
        if key in self._tiles:
            self._tiles.move_to_end(key)
            return self._tiles[key]
        origin = (i * self.tile_m, j * self.tile_m)
        levels = _mips(self._rasterize(origin, FINE_CELL_M, TILE_CELLS, TILE_CELLS), FINE_LEVELS)
        self._tiles[key] = levels
        while len(self._tiles) > 3 * WINDOW_TILES**2:
            self._tiles.popitem(last=False)
        return levels

    def follow(self, x_m: float, y_m: float) -> None:
        """Centre the fine window on the tile holding the camera at (x_m, y_m) [m]."""
        ci, cj = int(np.floor(x_m / self.tile_m)), int(np.floor(y_m / self.tile_m))
        if (ci, cj) == self._window:
            return
        h = WINDOW_TILES // 2
        self.fine.origin_xy = np.array([(ci - h) * self.tile_m, (cj - h) * self.tile_m])
        for a in range(WINDOW_TILES):
            for b in range(WINDOW_TILES):
                for k, lv in enumerate(self._tile(ci - h + a, cj - h + b)):
                    n = lv.shape[0]
                    self.fine.put(k, b * n, a * n, lv)
        self._window = (ci, cj)


def _bboxes(polys: list[np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    if not polys:
        return np.zeros((0, 2)), np.zeros((0, 2))
    return np.array([p.min(axis=0) for p in polys]), np.array([p.max(axis=0) for p in polys])


@dataclass(frozen=True)
class GroundLook:
    """What the plane looks like: its materials' albedo and how brightly each is lit.

    Shading is done on linear values, as in pyrender's shader: a pixel is
    ``255 * (sum of footprint weight * radiance) ** (1 / DISPLAY_GAMMA)``, a material's
    radiance being its irradiance factor times its linear albedo.

    asphalt, grass: periodic textures, linear albedo (`MipTexture` with ``srgb=True``);
    marking_albedo: (3,) linear albedo of the paint [-]; k_*: irradiance factors [-].
    """

    asphalt: MipTexture
    grass: MipTexture
    marking_albedo: np.ndarray
    k_road: float = 1.0
    k_grass: float = 1.0
    k_marking: float = 1.0


@dataclass
class LightMap:
    """What hides the light from the plane around a camera (`sim.shadows.cast_shadows`),
    on grids centred on the camera's (x, y), rows along y and columns along x, cell
    (0, 0)'s centre at -half_m + cell / 2 on both:

    sun: (N, N) uint8, 255 where the sun is hidden, over cells of sun_cell_m [m];
    sky: (K, K) float32, 0..1 the part of the sky hidden, over cells of sky_cell_m [m];
    near: (B, B) uint8, 1 on the blocks of near_cell_m [m] where either may be nonzero
    (their neighbours included): elsewhere the kernel reads neither;
    weights: (2,) what hiding all the sun, all the sky takes off the open road's light.
    A cell of 0: lit everywhere."""

    sun: np.ndarray
    sun_cell_m: float
    sky: np.ndarray
    sky_cell_m: float
    half_m: float
    near: np.ndarray
    near_cell_m: float
    weights: np.ndarray

    @staticmethod
    def lit() -> LightMap:
        """A map the kernel treats as fully lit (no vehicle near)."""
        none = np.zeros((1, 1), np.uint8)
        sky = np.zeros((1, 1), np.float32)
        return LightMap(none, 0.0, sky, 0.0, 0.0, none, 0.0, np.zeros(2))


@dataclass
class GroundImage:
    """The plane seen from one pose: rgb (H, W, 3) float32 [DN] where hit (blended with
    the sky where part of a pixel's footprint misses the plane), range_m (H, W) float32
    along the pixel's ray [m] (inf where it misses or is not drawn), hit (H, W) bool."""

    rgb: np.ndarray
    range_m: np.ndarray
    hit: np.ndarray


class GroundRenderer:
    """Renders the road plane for one camera.

    The probes of every pixel are camera rays, chosen once at a reference pose (the
    camera's nominal pose on its car: height and tilt above the plane): the footprint's
    major axis on the plane, seen back in the image, is where a pixel's probes lie; each
    probe's mip levels follow from its blur there. Per frame, only the probes' rays meet
    the plane at the actual pose: positions are exact; the footprint shapes are those of
    the nominal pose (vibration changes them by a few per cent: blur, not position).
    """

    def __init__(
        self,
        camera: CameraModel,
        T_world_cam_ref: np.ndarray,
        look: GroundLook,
        coverage: CoverageMap,
        sky_rgb: np.ndarray,
        pixels: np.ndarray | None = None,
    ) -> None:
        """sky_rgb: (3,) sky colour [DN]; pixels: (H, W) bool, the pixels to draw (default:
        the valid ones)."""
        self.camera, self.look, self.coverage = camera, look, coverage
        self.sky_linear = (np.asarray(sky_rgb, np.float64) / 255.0) ** DISPLAY_GAMMA
        H, W = camera.height, camera.width
        self.shape = (H, W)
        rays = camera.pixel_rays().reshape(-1, 3).astype(np.float64)
        R, o = T_world_cam_ref[:3, :3], T_world_cam_ref[:3, 3]
        d = rays @ R.T
        # pixels that may see the plane: rays below 1 deg above the horizon there
        pixels = camera.valid_mask() if pixels is None else np.asarray(pixels, bool)
        near = pixels.reshape(-1) & (d[:, 2] < np.sin(np.radians(1.0)))
        idx = np.flatnonzero(near)
        w = np.stack([idx % W, idx // W], axis=1).astype(np.float64)
        # pixels outside the valid view (the ring around the car body under an omni
        # mirror) are shown but never measured: fewer probes, a blurrier road
        cap = np.where(camera.valid_mask().reshape(-1)[idx], MAX_PROBES, OUTSIDE_VIEW_PROBES)
        foot = _footprints(camera, w, R, o, cap)
        # pixels whose probes all read the fine coverage window come first
        top_fine = FINE_CELL_M * 2.0 ** (FINE_LEVELS - 1)
        fine = (foot.far_m < 0.8 * coverage.reach_m) & (2.0 * foot.minor_m <= top_fine)
        order = np.argsort(~fine, kind="stable")
        self.pixel = idx[order]  # (N,) flat pixel index
        self.n_fine_pixels = int(fine.sum())
        n = foot.n[order]
        self.starts = np.concatenate([[0], np.cumsum(n)]).astype(np.int64)  # (N + 1,)
        pix = np.repeat(np.arange(len(n)), n)
        j = np.arange(len(pix)) - self.starts[pix]
        sel = order[pix]
        tau = np.where(n[pix] > 1, j / np.maximum(n[pix] - 1, 1) - 0.5, 0.0)  # -0.5..0.5
        w_probe = w[sel] + tau[:, None] * foot.extent_px[sel]
        self.probe_rays = np.nan_to_num(camera.unproject(w_probe))  # (P, 3)
        wt = np.exp(-0.5 * (4.0 * tau) ** 2)  # Gaussian over +-2 spread
        self.weight = wt / np.add.reduceat(wt, self.starts[:-1])[pix]  # (P,)
        self._blur = foot.blur_m[sel]  # (P,) [m]
        self._minor = foot.minor_m[sel]  # (P,) [m]
        self.centre_rays = rays[self.pixel]  # (N, 3)
        self.set_plane(look, coverage)

    def set_plane(self, look: GroundLook, coverage: CoverageMap) -> None:
        """What the plane looks like and where its road is (the probes stay)."""
        self.look, self.coverage = look, coverage
        blur, nf = self._blur, int(self.starts[self.n_fine_pixels])
        self.lvl_asphalt = look.asphalt.levels(blur)
        self.lvl_grass = look.grass.levels(blur)
        # the coverage (painted edges) at the footprint's minor axis: see the module's doc
        sharp = self._minor
        fine_lv, coarse_lv = coverage.fine.levels(sharp[:nf]), coverage.coarse.levels(sharp[nf:])
        self.lvl_cover = tuple(np.concatenate(p) for p in zip(fine_lv, coarse_lv, strict=True))

    @property
    def probes(self) -> int:
        return len(self.weight)

    def render(self, T_world_cam: np.ndarray) -> GroundImage:
        """The plane seen from T_world_cam (4, 4), on the sky."""
        H, W = self.shape
        sky = np.float32(255.0) * self.sky_linear.astype(np.float32) ** (1.0 / DISPLAY_GAMMA)
        image = np.empty((H, W, 3), np.float32)
        image[:] = sky
        range_m = np.full((H, W), np.inf, np.float32)
        hit = self.render_into(T_world_cam, image, range_m)
        return GroundImage(image, range_m, hit)

    def render_into(
        self,
        T_world_cam: np.ndarray,
        image: np.ndarray,
        range_m: np.ndarray,
        light: LightMap | None = None,
    ) -> np.ndarray:
        """Draw the plane seen from T_world_cam (4, 4) into image (H, W, 3) float32 [DN]
        and range_m (H, W) float32 [m] (where a pixel's centre ray meets it), lit as light
        says (`LightMap`, `sim.shadows.cast_shadows` around the camera; default: fully
        lit); returns the (H, W) bool pixels drawn."""
        R, o = T_world_cam[:3, :3].astype(np.float64), T_world_cam[:3, 3].astype(np.float64)
        cm, look = self.coverage, self.look
        lm = LightMap.lit() if light is None else light
        cm.follow(float(o[0]), float(o[1]))
        paint = np.asarray(look.marking_albedo, np.float64) * look.k_marking
        _shade(
            self.probe_rays, self.weight, self.starts, self.n_fine_pixels, R, o,
            _atlas_args(look.asphalt, o), self.lvl_asphalt[0], self.lvl_asphalt[1],
            _atlas_args(look.grass, o), self.lvl_grass[0], self.lvl_grass[1],
            _atlas_args(cm.fine, o), _atlas_args(cm.coarse, o),
            self.lvl_cover[0], self.lvl_cover[1],
            float(look.k_road), float(look.k_grass), paint,
            lm.sun, float(lm.sun_cell_m), lm.sky, float(lm.sky_cell_m), float(lm.half_m),
            lm.near, float(lm.near_cell_m), np.asarray(lm.weights, np.float64), self.sky_linear,
            1.0 / DISPLAY_GAMMA, MAX_RANGE_M, self.pixel, self.centre_rays,
            image.reshape(-1, 3), range_m.reshape(-1),
        )  # fmt: skip
        hit = np.zeros(image.shape[:2], bool)
        hit.reshape(-1)[self.pixel] = True
        return hit


def _atlas_args(a: MipAtlas, o: np.ndarray) -> tuple:
    """What the kernel reads of an atlas: the atlas, per-level cells per metre, period and
    column, the row of cell (0, 0), and the camera's offset from the atlas' origin [m]
    (modulo a periodic atlas' period, so that the kernel's numbers stay small)."""
    off = o[:2] - a.origin_xy
    if a.period[0] > 0:
        off = np.mod(off, a.period[0] * a.cell_m)
    return (a.atlas, a.per_m, a.period, a.col, a.row0, float(off[0]), float(off[1]), a.inv_period)


@njit(cache=True, inline="always", fastmath=_FAST)
def _coords(args, level, x, y):
    """Atlas coordinates [cells] at a mip level of the plane point (x, y) [m], given
    relative to the camera."""
    per, period = args[1][level], args[2][level]
    u = (x + args[5]) * per - 0.5
    v = (y + args[6]) * per - 0.5
    if period > 0.0:
        inv = args[7][level]
        u -= np.floor(u * inv) * period
        v -= np.floor(v * inv) * period
    return u + args[3][level], v + args[4]


@njit(cache=True, inline="always", fastmath=_FAST)
def _bilinear3(atlas, x, y):
    """Bilinear sample (3 channels) of atlas (R, C, 3) at centre-index coordinates
    (x, y) [cells]; zero where a neighbour is outside."""
    x0f, y0f = np.floor(x), np.floor(y)
    fx, fy = x - x0f, y - y0f
    x0, y0 = int(x0f), int(y0f)
    if x0 < 0 or y0 < 0 or x0 + 1 >= atlas.shape[1] or y0 + 1 >= atlas.shape[0]:
        return 0.0, 0.0, 0.0
    w00, w01 = (1.0 - fx) * (1.0 - fy), fx * (1.0 - fy)
    w10, w11 = (1.0 - fx) * fy, fx * fy
    a, b = atlas[y0, x0], atlas[y0, x0 + 1]
    c, d = atlas[y0 + 1, x0], atlas[y0 + 1, x0 + 1]
    return (
        w00 * a[0] + w01 * b[0] + w10 * c[0] + w11 * d[0],
        w00 * a[1] + w01 * b[1] + w10 * c[1] + w11 * d[1],
        w00 * a[2] + w01 * b[2] + w10 * c[2] + w11 * d[2],
    )


@njit(cache=True, inline="always", fastmath=_FAST)
def _trilinear3(args, level, frac, x, y):
    """Trilinear sample (3 channels) of a `MipAtlas` (`_atlas_args`) at the plane point
    (x, y) [m] relative to the camera."""
    u, v = _coords(args, level, x, y)
    r, g, b = _bilinear3(args[0], u, v)
    if frac > 0.0:
        u, v = _coords(args, level + 1, x, y)
        r1, g1, b1 = _bilinear3(args[0], u, v)
        r += frac * (r1 - r)
        g += frac * (g1 - g)
        b += frac * (b1 - b)
    return r, g, b


@njit(cache=True, inline="always", fastmath=_FAST)
def _bilinear2(atlas, x, y):
    """Bilinear sample (2 channels) of atlas (R, C, >=2) at centre-index coordinates
    (x, y) [cells]; zero where a neighbour is outside."""
    x0f, y0f = np.floor(x), np.floor(y)
    fx, fy = x - x0f, y - y0f
    x0, y0 = int(x0f), int(y0f)
    if x0 < 0 or y0 < 0 or x0 + 1 >= atlas.shape[1] or y0 + 1 >= atlas.shape[0]:
        return 0.0, 0.0
    w00, w01 = (1.0 - fx) * (1.0 - fy), fx * (1.0 - fy)
    w10, w11 = (1.0 - fx) * fy, fx * fy
    c0 = w00 * atlas[y0, x0, 0] + w01 * atlas[y0, x0 + 1, 0]
    c0 += w10 * atlas[y0 + 1, x0, 0] + w11 * atlas[y0 + 1, x0 + 1, 0]
    c1 = w00 * atlas[y0, x0, 1] + w01 * atlas[y0, x0 + 1, 1]
    c1 += w10 * atlas[y0 + 1, x0, 1] + w11 * atlas[y0 + 1, x0 + 1, 1]
    return c0, c1


@njit(cache=True, inline="always", fastmath=_FAST)
def _cover_at(args, level, frac, x, y):
    """The coverage (road, marking) 0..1 of a coverage `MipAtlas` (`_atlas_args`) at the
    plane point (x, y) [m] relative to the camera, trilinear."""
    u, v = _coords(args, level, x, y)
    r, m = _bilinear2(args[0], u, v)
    if frac > 0.0:
        u, v = _coords(args, level + 1, x, y)
        r1, m1 = _bilinear2(args[0], u, v)
        r += frac * (r1 - r)
        m += frac * (m1 - m)
    return r / 255.0, m / 255.0


@njit(cache=True, inline="always", fastmath=_FAST)
def _near(near, cell, half, x, y):
    """Whether the plane point (x, y) [m] relative to the camera lies on a block of the
    light grids that is not fully lit (`LightMap.near`; never without one)."""
    if cell <= 0.0:
        return False
    i = int(np.floor((x + half) / cell))
    j = int(np.floor((y + half) / cell))
    return 0 <= i < near.shape[1] and 0 <= j < near.shape[0] and near[j, i] != 0


@njit(cache=True, inline="always", fastmath=_FAST)
def _grid_at(grid, cell, half, x, y):
    """Bilinear sample of a 2-D grid (`LightMap`) at the plane point (x, y)
    [m] relative to the camera; 0 outside it or without one (cell 0)."""
    if cell <= 0.0:
        return 0.0
    u = (x + half) / cell - 0.5
    v = (y + half) / cell - 0.5
    x0f, y0f = np.floor(u), np.floor(v)
    x0, y0 = int(x0f), int(y0f)
    if x0 < 0 or y0 < 0 or x0 + 1 >= grid.shape[1] or y0 + 1 >= grid.shape[0]:
        return 0.0
    fx, fy = u - x0f, v - y0f
    a, b = float(grid[y0, x0]), float(grid[y0, x0 + 1])
    c, d = float(grid[y0 + 1, x0]), float(grid[y0 + 1, x0 + 1])
    top = a + fx * (b - a)
    return top + fy * (c + fx * (d - c) - top)


@njit(cache=True, inline="always", fastmath=_FAST)
def _plane_point(rays, p, R, o, max_range):
    """Where probe p's ray (camera frame) seen from pose (R, o) meets the plane: (hit,
    x, y) [m] relative to the camera."""
    dx = R[0, 0] * rays[p, 0] + R[0, 1] * rays[p, 1] + R[0, 2] * rays[p, 2]
    dy = R[1, 0] * rays[p, 0] + R[1, 1] * rays[p, 1] + R[1, 2] * rays[p, 2]
    dz = R[2, 0] * rays[p, 0] + R[2, 1] * rays[p, 1] + R[2, 2] * rays[p, 2]
    if dz >= 0.0 or -o[2] >= max_range * -dz:
        return False, 0.0, 0.0
    t = -o[2] / dz
    return True, t * dx, t * dy


@njit(parallel=True, cache=True, nogil=True, error_model="numpy", fastmath=_FAST)
def _shade(
    rays, weight, starts, n_fine, R, o, asphalt, la, fa, grass, lg, fg, fine, coarse, lc, fc,
    k_road, k_grass, paint, sun, sun_cell, sky_hidden, sky_cell, half, near, near_cell,
    light_w, sky, inv_gamma, max_range, pixel, centre, out_rgb, out_range,
):  # fmt: skip
    """The colour [DN] of every pixel (N,) into out_rgb[pixel] (HW, 3), and the range of
    its centre ray (N, 3) into out_range[pixel] (HW,) where it meets the plane: its
    probes' rays (P, 3) meet the plane seen from pose (R, o) and read the coverage (the
    fine window for the first n_fine pixels, else the coarse map) and the textures, each
    trilinear, lit as the grids of the sun and sky hidden say (`_grid_at`, weighted by
    light_w (2,), read on the blocks `_near` names); the part of the footprint off the
    plane is sky (linear, (3,))."""
    for i in prange(len(starts) - 1):
        acc0, acc1, acc2 = 0.0, 0.0, 0.0
        cover = 0.0
        cm = fine if i < n_fine else coarse
        s0, n = starts[i], starts[i + 1] - starts[i]
        # a window of three probes along the major axis: the one before, this, the next
        hit_b, x_b, y_b, r_b, m_b = False, 0.0, 0.0, 0.0, 0.0
        hit, x, y = _plane_point(rays, s0, R, o, max_range)
        r, m = _cover_at(cm, lc[s0], fc[s0], x, y) if hit else (0.0, 0.0)
        for q in range(n):
            p = s0 + q
            hit_n, x_n, y_n, r_n, m_n = False, 0.0, 0.0, 0.0, 0.0
            if q + 1 < n:
                hit_n, x_n, y_n = _plane_point(rays, p + 1, R, o, max_range)
                if hit_n:
                    r_n, m_n = _cover_at(cm, lc[p + 1], fc[p + 1], x_n, y_n)
            if hit:
                road, mark = r, m
                # an edge of the coverage within the probe's cell: its mean over the cell,
                # which reaches halfway to each neighbour (a lone end mirrors the other)
                edge = (hit_b and abs(r_b - r) + abs(m_b - m) > COVER_EDGE) or (
                    hit_n and abs(r_n - r) + abs(m_n - m) > COVER_EDGE
                )
                if edge:
                    ax, ay = (0.5 * (x_b - x), 0.5 * (y_b - y)) if hit_b else (0.0, 0.0)
                    bx, by = (0.5 * (x_n - x), 0.5 * (y_n - y)) if hit_n else (-ax, -ay)
                    if not hit_b:
                        ax, ay = -bx, -by
                    road, mark = 0.0, 0.0
                    for k in range(COVER_SUBSAMPLES):
                        f = (k + 0.5) / COVER_SUBSAMPLES
                        rs, ms = _cover_at(
                            cm, lc[p], fc[p], x + ax + f * (bx - ax), y + ay + f * (by - ay)
                        )
                        road += rs
                        mark += ms
                    road /= COVER_SUBSAMPLES
                    mark /= COVER_SUBSAMPLES
                t0, t1, t2 = 0.0, 0.0, 0.0
                if road > 0.0:
                    a0, a1, a2 = _trilinear3(asphalt, la[p], fa[p], x, y)
                    ka = road * k_road
                    t0, t1, t2 = ka * a0, ka * a1, ka * a2
                if road < 1.0:
                    g0, g1, g2 = _trilinear3(grass, lg[p], fg[p], x, y)
                    kg = (1.0 - road) * k_grass
                    t0, t1, t2 = t0 + kg * g0, t1 + kg * g1, t2 + kg * g2
                w = weight[p]
                lw = w
                if _near(near, near_cell, half, x, y):
                    # light: 1 - the parts of the sun and sky hidden, weighted (`sim.shadows`)
                    lw = w * (
                        1.0
                        - light_w[0] * _grid_at(sun, sun_cell, half, x, y) / 255.0
                        - light_w[1] * _grid_at(sky_hidden, sky_cell, half, x, y)
                    )
                acc0 += lw * (t0 + mark * (paint[0] - t0))
                acc1 += lw * (t1 + mark * (paint[1] - t1))
                acc2 += lw * (t2 + mark * (paint[2] - t2))
                cover += w
            hit_b, x_b, y_b, r_b, m_b = hit, x, y, r, m
            hit, x, y, r, m = hit_n, x_n, y_n, r_n, m_n
        miss = 1.0 - cover
        k = pixel[i]
        out_rgb[k, 0] = 255.0 * max(acc0 + miss * sky[0], 0.0) ** inv_gamma
        out_rgb[k, 1] = 255.0 * max(acc1 + miss * sky[1], 0.0) ** inv_gamma
        out_rgb[k, 2] = 255.0 * max(acc2 + miss * sky[2], 0.0) ** inv_gamma
        dz = R[2, 0] * centre[i, 0] + R[2, 1] * centre[i, 1] + R[2, 2] * centre[i, 2]
        if dz < 0.0 and -o[2] < max_range * -dz:
            out_range[k] = -o[2] / dz


@dataclass
class _Footprints:
    """Per pixel (N,): probe count n, image extent of the probes (N, 2) [px] (from the
    first to the last), spread along the major axis [m], each probe's blur [m], the
    farthest reach of the footprint from the camera [m] and its minor-axis std [m]."""

    n: np.ndarray
    extent_px: np.ndarray
    spread_m: np.ndarray
    blur_m: np.ndarray
    far_m: np.ndarray
    minor_m: np.ndarray


def _footprints(
    camera: CameraModel, w: np.ndarray, R: np.ndarray, o: np.ndarray, max_probes: np.ndarray
) -> _Footprints:
    """Footprints on the plane of the pixels w (N, 2) [px] seen from pose (R, o), with at
    most max_probes (N,) probes each."""

    def plane_xy(wp: np.ndarray) -> np.ndarray:
        d = camera.unproject(wp) @ R.T
        with np.errstate(divide="ignore", invalid="ignore"):
            t = -o[2] / d[:, 2]
        t = np.where(d[:, 2] < -1e-9, t, np.nan)
        return np.stack([t * d[:, 0], t * d[:, 1]], axis=1)

    # Jacobian of the plane point on the pixel [m/px], central differences (+-0.5 px);
    # pixels above the horizon get the one of a ray just below it (their probes miss)
    Ju = plane_xy(w + (0.5, 0.0)) - plane_xy(w - (0.5, 0.0))
    Jv = plane_xy(w + (0.0, 0.5)) - plane_xy(w - (0.0, 0.5))
    bad = ~np.all(np.isfinite(np.concatenate([Ju, Jv], axis=1)), axis=1)
    Ju[bad], Jv[bad] = (MAX_RANGE_M * 0.01, 0.0), (0.0, MAX_RANGE_M * 0.01)
    s2 = PIXEL_SIGMA_PX**2
    a = s2 * (Ju[:, 0] ** 2 + Jv[:, 0] ** 2)
    b = s2 * (Ju[:, 0] * Ju[:, 1] + Jv[:, 0] * Jv[:, 1])
    c = s2 * (Ju[:, 1] ** 2 + Jv[:, 1] ** 2)
    mid, rad = 0.5 * (a + c), np.sqrt(0.25 * (a - c) ** 2 + b**2)
    major2, minor2 = mid + rad, np.maximum(mid - rad, 1e-12)
    theta = 0.5 * np.arctan2(2.0 * b, a - c)
    e = np.stack([np.cos(theta), np.sin(theta)], axis=1)  # major axis on the plane
    spread = np.sqrt(np.maximum(major2 - minor2, 0.0))  # Gaussian the probes spread [m]
    minor = np.sqrt(minor2)
    # probes over +-2 spread, at most two blur std apart
    n = np.clip(np.ceil(2.0 * spread / minor) + 1.0, 1, max_probes).astype(np.int64)
    n[spread < 0.5 * minor] = 1
    blur = np.maximum(minor, 2.0 * spread / np.maximum(n - 1, 1))
    blur[n == 1] = np.sqrt(major2[n == 1])
    # the probes' span on the plane (4 spread along e) seen in the image [px]
    J = np.stack([Ju, Jv], axis=2)  # (N, 2, 2): columns d(xy)/du, d(xy)/dv
    Jinv = np.linalg.inv(J + 1e-12 * np.eye(2))
    extent = np.einsum("nij,nj->ni", Jinv, 4.0 * spread[:, None] * e)
    xy = plane_xy(w)
    far = np.hypot(xy[:, 0], xy[:, 1]) + 2.0 * spread
    far = np.where(np.isfinite(far), far, np.inf)
    return _Footprints(n, extent, spread, blur, far, minor)
