"""Trimesh geometry of the world: road, markings, roadside, vehicles.

World frame (docs/CONVENTIONS.md): right-handed, z up, metres, the road surface
at z = 0. Everything here is plain trimesh; the renderer (pyrender) turns each
returned mesh into one node. pyrender's cost is per node, not per pixel (the
per-mesh-node cost of OSMesa rendering, docs/INSTALL.md), so this module returns FEW
merged meshes:

- :func:`build_static_scene` -> up to 4 meshes, each named in ``mesh.metadata["name"]``:
  ``"road"`` (textured asphalt, shoulders included), ``"markings"`` (vertex
  colours), ``"ground"`` (textured grass) and ``"roadside"`` (vertex colours:
  guard-rails, kerbs, sidewalks, poles, trees, buildings, obstacles).
- :func:`vehicles_mesh` -> ONE mesh with every vehicle, built by instancing a car
  template with numpy.

Each mesh either has a texture (``TextureVisuals`` with a PIL image, UVs in world
metres / tile size so the tileable texture repeats) or per-vertex RGBA colours
(uint8). Meshes are built with ``process=False`` so trimesh never merges or
reorders vertices (the id colours must stay exact).

Vehicle box: (x_m, y_m) is the centre of the footprint on the road, length along
the yaw, width across, from z = 0 (wheels) to z = height_m. The body starts about
0.15 m above the road.

Vehicle ids in images: ``mode="id"`` paints vehicle ``id`` with the 24-bit value
``id + 1`` (R = value & 255, G = (value >> 8) & 255, B = value >> 16); a render
without lighting or anti-aliasing (pyrender ``RenderFlags.FLAT``) then gives a
per-pixel id image, decoded by :func:`decode_id_image` (-1 where no vehicle).
Static meshes must be drawn black in that pass (:func:`id_occluder_mesh`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh
from PIL import Image

from sim.highway import LaneGeometry, RoadGeometry, VehicleState, check_box
from sim.textures import asphalt_texture, grass_texture

ASPHALT_TILE_M = 4.5  # [m] one asphalt texture tile (512 px: ~9 mm per texel)
ASPHALT_PX = 512  # [px]
GRASS_TILE_M = 4.0  # [m]
GRASS_PX = 256  # [px]
ROAD_STEP_M = 2.0  # [m] largest sample spacing along a lane for the meshes
LANE_OVERLAP_M = 0.05  # [m] each lane strip is grown by this on its sides and ends
SHOULDER_M = 1.0  # [m] asphalt beyond a continuous edge line
MARK_WIDTH_M = 0.15  # [m]
DASH_ON_M = 3.0  # [m] painted part of a striped line
DASH_OFF_M = 9.0  # [m] gap of a striped line
# The road, its markings and the grass all lie in the road plane z = 0; which of them is
# seen where they overlap is settled by depth offsets when drawn (`sim.gl`), by mesh name:
# markings before the road before the grass. All three are pushed back (> 0), none pulled
# forward: nothing lies below the road, so pushing it back cannot hide what stands on it
# (a surface pulled forward by a pixel's worth of depth slope could cover it; not seen in
# `tests/sim/test_renderer.py`, but not possible this way). Lifting the markings 1 cm and
# dropping the grass 3 cm, as before, put them off the plane the estimator assumes: seen
# from the omni camera, markings 0.5 % nearer and grass 1.5 % farther than the road.
DEPTH_OFFSET = {"markings": 1.0, "road": 2.0, "ground": 3.0}
URBAN_SPEED_MPS = 12.0  # [m/s] at or below: kerbs, sidewalks, buildings; above: guard-rails

STRIPED, CONTINUOUS, CONTINUOUS_LINE = 1, 2, 3  # highway-env LineType codes
WHITE = (238, 238, 232, 255)

VEHICLE_MODES = ("color", "id")


# --------------------------------------------------------------------------- helpers


def _check_rng(rng: object) -> np.random.Generator:
    if not isinstance(rng, np.random.Generator):
        raise TypeError(f"rng must be a np.random.Generator, got {type(rng).__name__}")
    return rng


def _unmerged(mesh: trimesh.Trimesh) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(V, 3) vertices, (F, 3) faces, (V, 3) normals with every face owning its vertices."""
    v = mesh.vertices[mesh.faces].reshape(-1, 3)
    f = np.arange(len(v)).reshape(-1, 3)
    n = np.repeat(mesh.face_normals, 3, axis=0)
    return v, f, n


class _Parts:
    """Accumulates (vertices, faces, normals, colours) and builds one mesh."""

    def __init__(self) -> None:
        self.v: list[np.ndarray] = []
        self.f: list[np.ndarray] = []
        self.n: list[np.ndarray] = []
        self.c: list[np.ndarray] = []
        self.count = 0

    def add(self, v: np.ndarray, f: np.ndarray, n: np.ndarray, c: np.ndarray) -> None:
        if len(f) == 0:
            return
        self.v.append(np.asarray(v, float))
        self.f.append(np.asarray(f, np.int64) + self.count)
        self.n.append(np.asarray(n, float))
        c = np.asarray(c, np.uint8)
        self.c.append(np.broadcast_to(c, (len(v), 4)) if c.ndim == 1 else c)
        self.count += len(v)

    def mesh(self, name: str) -> trimesh.Trimesh | None:
        if not self.v:
            return None
        m = trimesh.Trimesh(
            vertices=np.concatenate(self.v),
            faces=np.concatenate(self.f),
            vertex_normals=np.concatenate(self.n),
            vertex_colors=np.concatenate(self.c),
            process=False,
        )
        m.metadata["name"] = name
        return m


def _instances(
    v: np.ndarray,
    f: np.ndarray,
    n: np.ndarray,
    xy: np.ndarray,
    yaw: np.ndarray,
    scale: np.ndarray,
    z: np.ndarray | float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose M copies of a template (V, 3) by scale (M, 3), yaw (M,), xy (M, 2), z.

    Returns (M*V, 3) vertices, (M*F, 3) faces, (M*V, 3) normals (inverse-transpose
    of the scale, then rotated).
    """
    m = len(xy)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    verts = _posed_points(v, xy, c, s, scale, z)
    ns = n[None, :, :] / scale[:, None, :]
    ns /= np.maximum(np.sqrt(np.sum(ns * ns, axis=-1, keepdims=True)), 1e-12)
    norms = np.empty_like(ns)
    norms[..., 0] = c * ns[..., 0] - s * ns[..., 1]
    norms[..., 1] = s * ns[..., 0] + c * ns[..., 1]
    norms[..., 2] = ns[..., 2]
    faces = f[None, :, :] + (np.arange(m) * len(v))[:, None, None]
    return verts.reshape(-1, 3), faces.reshape(-1, 3), norms.reshape(-1, 3)


def _posed_points(
    v: np.ndarray,
    xy: np.ndarray,
    c: np.ndarray,
    s: np.ndarray,
    scale: np.ndarray,
    z: np.ndarray | float = 0.0,
) -> np.ndarray:
    """(M, V, 3) points v (V, 3) scaled by scale (M, 3), turned by the yaw whose cosine
    and sine are c, s (M, 1) and moved to xy (M, 2), z."""
    vs = v[None, :, :] * scale[:, None, :]
    out = np.empty_like(vs)
    out[..., 0] = c * vs[..., 0] - s * vs[..., 1] + xy[:, 0, None]
    out[..., 1] = s * vs[..., 0] + c * vs[..., 1] + xy[:, 1, None]
    out[..., 2] = vs[..., 2] + np.broadcast_to(np.asarray(z, float), (len(xy),))[:, None]
    return out


def _box(lo: Sequence[float], hi: Sequence[float]) -> tuple[np.ndarray, ...]:
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    b = trimesh.creation.box(extents=hi - lo)
    b.apply_translation((lo + hi) / 2)
    return _unmerged(b)


def _polyline_frame(pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N,) arclength and (N, 2) unit left normals of a polyline (N >= 2)."""
    d = np.gradient(pts, axis=0)
    d /= np.maximum(np.linalg.norm(d, axis=1, keepdims=True), 1e-12)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(pts, axis=0), axis=1))])
    return s, np.stack([-d[:, 1], d[:, 0]], axis=1)


def _strip(
    left: np.ndarray, right: np.ndarray, z: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A flat triangle strip between two (..., N, 2) polylines, facing up.

    Leading batch dimensions give independent strips.
    """
    left, right = np.asarray(left, float), np.asarray(right, float)
    batch = left.shape[:-2]
    nb = int(np.prod(batch)) if batch else 1
    left = left.reshape(nb, -1, 2)
    right = right.reshape(nb, -1, 2)
    n = left.shape[1]
    v = np.empty((nb, n, 2, 3))
    v[:, :, 0, :2], v[:, :, 1, :2], v[..., 2] = left, right, z
    i = np.arange(n - 1)
    L, R = 2 * i, 2 * i + 1
    # (R_i, R_i+1, L_i) and (L_i, R_i+1, L_i+1) are counter-clockwise seen from +z
    f = np.concatenate([np.stack([R, R + 2, L], 1), np.stack([L, R + 2, L + 2], 1)], axis=0)
    faces = (f[None] + (np.arange(nb) * 2 * n)[:, None, None]).reshape(-1, 3)
    verts = v.reshape(-1, 3)
    normals = np.zeros_like(verts)
    normals[:, 2] = 1.0
    return verts, faces, normals


def _sweep(
    path: np.ndarray, left_n: np.ndarray, profile: np.ndarray, z0: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sweep a closed (P, 2) profile of (lateral, z), counter-clockwise, along a path.

    path (N, 2) with unit left normals (N, 2). Each profile edge gets its own
    vertices (flat shading); normals point out of the profile.
    """
    nn, p = len(path), len(profile)
    verts, faces, norms = [], [], []
    base = 0
    for j in range(p):
        a0, z_0 = profile[j]
        a1, z_1 = profile[(j + 1) % p]
        q0 = np.column_stack([path + a0 * left_n, np.full(nn, z0 + z_0)])
        q1 = np.column_stack([path + a1 * left_n, np.full(nn, z0 + z_1)])
        v = np.stack([q0, q1], axis=1).reshape(-1, 3)  # (2N, 3): q0_i, q1_i
        i = np.arange(nn - 1)
        A, B = 2 * i, 2 * i + 1
        # counter-clockwise profile => this winding makes the normals point outward
        f = np.concatenate([np.stack([A, B, A + 2], 1), np.stack([B, B + 2, A + 2], 1)])
        # outward normal of edge (a0,z0)->(a1,z1) in the (lateral, z) plane: (dz, -da)
        da, dz = a1 - a0, z_1 - z_0
        ln = np.hypot(da, dz)
        nrm = np.column_stack([left_n * (dz / ln), np.full(nn, -da / ln)])
        verts.append(v)
        faces.append(f + base)
        norms.append(np.repeat(nrm, 2, axis=0))
        base += len(v)
    return np.concatenate(verts), np.concatenate(faces), np.concatenate(norms)


def _resample_lane(lane: LaneGeometry, step: float) -> LaneGeometry:
    """Insert samples so that no gap along s exceeds ``step`` (linear interpolation)."""
    s = lane.s_m
    gaps = np.diff(s)
    if len(s) < 2 or gaps.max() <= step:
        return lane
    k = np.maximum(1, np.ceil(gaps / step).astype(int))
    s_new = np.concatenate(
        [np.linspace(a, b, n, endpoint=False) for a, b, n in zip(s[:-1], s[1:], k, strict=True)]
        + [s[-1:]]
    )

    def lerp(x: np.ndarray) -> np.ndarray:
        if x.ndim == 1:
            return np.interp(s_new, s, x)
        return np.stack([np.interp(s_new, s, x[:, j]) for j in range(x.shape[1])], axis=1)

    yaw = np.unwrap(lane.yaw_rad)
    return LaneGeometry(
        index=lane.index,
        s_m=s_new,
        center_xy=lerp(lane.center_xy),
        left_xy=lerp(lane.left_xy),
        right_xy=lerp(lane.right_xy),
        yaw_rad=lerp(yaw),
        width_m=lerp(lane.width_m),
        line_types=lane.line_types,
        speed_limit_mps=lane.speed_limit_mps,
        kind=lane.kind,
    )


def _left_normals(lane: LaneGeometry) -> np.ndarray:
    return np.stack([-np.sin(lane.yaw_rad), np.cos(lane.yaw_rad)], axis=1)


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    d = np.diff(np.concatenate([[0], np.asarray(mask, np.int8), [0]]))
    return list(zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True))


def _textured(
    v: np.ndarray, f: np.ndarray, n: np.ndarray, image: np.ndarray, tile_m: float, name: str
) -> trimesh.Trimesh:
    uv = v[:, :2] / tile_m
    visual = trimesh.visual.TextureVisuals(uv=uv, image=Image.fromarray(image))
    m = trimesh.Trimesh(vertices=v, faces=f, vertex_normals=n, visual=visual, process=False)
    m.metadata["name"] = name
    m.metadata["tile_m"] = tile_m
    return m


# --------------------------------------------------------------------------- static scene


def build_static_scene(
    road: RoadGeometry,
    area_xy: Sequence[float],
    rng: np.random.Generator,
    *,
    style: str = "auto",
) -> list[trimesh.Trimesh]:
    """Meshes of everything that does not move, inside ``area_xy`` (world, [m]).

    road: the road (any extent; clipped here to ``area_xy``).
    area_xy: (xmin, xmax, ymin, ymax) of the area to build [m].
    rng: draws the textures and the roadside objects (same seed -> same scene).
    style: ``"rural"`` (guard-rails, light poles, trees), ``"urban"`` (kerbs,
        sidewalks, buildings, trees) or ``"auto"`` (urban where a lane's speed
        limit is at most ``URBAN_SPEED_MPS``).

    Returns up to 4 meshes named ``road``, ``markings``, ``ground``, ``roadside``
    (see the module docstring).
    """
    area = check_box(area_xy, "area_xy")
    _check_rng(rng)
    if style not in ("auto", "rural", "urban"):
        raise ValueError(f"style must be 'auto', 'rural' or 'urban', got {style!r}")
    clipped = road.clipped(area, margin_m=2.0)
    lanes = [_resample_lane(ln, ROAD_STEP_M) for ln in clipped.lanes]
    lanes = [ln for ln in lanes if len(ln.s_m) >= 2]
    geo = RoadGeometry(lanes=tuple(lanes), obstacles_xyyaw_lw=clipped.obstacles_xyyaw_lw)

    def urban(lane: LaneGeometry) -> bool:
        if style != "auto":
            return style == "urban"
        return lane.speed_limit_mps is not None and lane.speed_limit_mps <= URBAN_SPEED_MPS

    meshes = []
    if lanes:
        meshes.append(_road_mesh(lanes, rng))
        mk = _markings_mesh(lanes)
        if mk is not None:
            meshes.append(mk)
    meshes.append(_ground_mesh(area, rng))
    side = _roadside_mesh(geo, area, rng, urban)
    if side is not None:
        meshes.append(side)
    return meshes


def _road_mesh(lanes: list[LaneGeometry], rng: np.random.Generator) -> trimesh.Trimesh:
    parts_v, parts_f, parts_n, base = [], [], [], 0
    for lane in lanes:
        nl = _left_normals(lane)
        grow_l = LANE_OVERLAP_M + (SHOULDER_M if lane.line_types[0] >= CONTINUOUS else 0.0)
        grow_r = LANE_OVERLAP_M + (SHOULDER_M if lane.line_types[1] >= CONTINUOUS else 0.0)
        left, right = lane.left_xy + grow_l * nl, lane.right_xy - grow_r * nl
        # overlap the next/previous lane piece too: no hairline cracks at lane joints
        t = np.stack([nl[:, 1], -nl[:, 0]], axis=1)
        for pts in (left, right):
            pts[0] -= LANE_OVERLAP_M * t[0]
            pts[-1] += LANE_OVERLAP_M * t[-1]
        v, f, n = _strip(left, right, 0.0)
        parts_v.append(v)
        parts_f.append(f + base)
        parts_n.append(n)
        base += len(v)
    image = asphalt_texture(rng, ASPHALT_PX)
    return _textured(
        np.concatenate(parts_v),
        np.concatenate(parts_f),
        np.concatenate(parts_n),
        image,
        ASPHALT_TILE_M,
        "road",
    )


def _markings_mesh(lanes: list[LaneGeometry]) -> trimesh.Trimesh | None:
    parts = _Parts()
    half = MARK_WIDTH_M / 2
    period = DASH_ON_M + DASH_OFF_M
    for lane in lanes:
        nl = _left_normals(lane)
        s = lane.s_m
        for side, edge, sign in ((0, lane.left_xy, 1.0), (1, lane.right_xy, -1.0)):
            kind = lane.line_types[side]
            centre = edge
            if kind in (CONTINUOUS, CONTINUOUS_LINE):
                # an edge line is painted on its lane: inset by half its width
                centre = edge - sign * half * nl
                v, f, n = _strip(centre + half * nl, centre - half * nl, 0.0)
                parts.add(v, f, n, np.array(WHITE, np.uint8))
            elif kind == STRIPED:
                k = np.arange(np.floor(s[0] / period), np.ceil(s[-1] / period) + 1)
                a = np.clip(k * period, s[0], s[-1])
                b = np.clip(k * period + DASH_ON_M, s[0], s[-1])
                keep = b - a > 0.2
                if not keep.any():
                    continue
                t = np.linspace(0.0, 1.0, 4)
                sd = a[keep, None] + (b - a)[keep, None] * t[None, :]  # (M, 4)
                cx = np.interp(sd, s, centre[:, 0])
                cy = np.interp(sd, s, centre[:, 1])
                yaw = np.interp(sd, s, np.unwrap(lane.yaw_rad))
                nx, ny = -np.sin(yaw), np.cos(yaw)
                lft = np.stack([cx + half * nx, cy + half * ny], axis=-1)
                rgt = np.stack([cx - half * nx, cy - half * ny], axis=-1)
                v, f, n = _strip(lft, rgt, 0.0)
                parts.add(v, f, n, np.array(WHITE, np.uint8))
    return parts.mesh("markings")


def ground_grid(area: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(v, f, n) of the ground: a grid of ~25-m cells over area (xmin, xmax, ymin, ymax)
    [m] in the road plane (z = 0), one strip per row of cells (facing +z)."""
    xmin, xmax, ymin, ymax = area
    nx = max(1, int(np.ceil((xmax - xmin) / 25.0)))
    ny = max(1, int(np.ceil((ymax - ymin) / 25.0)))
    xs, ys = np.linspace(xmin, xmax, nx + 1), np.linspace(ymin, ymax, ny + 1)
    # left = upper row, right = lower row
    upper = np.stack(np.broadcast_arrays(xs[None, :], ys[1:, None]), axis=-1)
    lower = np.stack(np.broadcast_arrays(xs[None, :], ys[:-1, None]), axis=-1)
    return _strip(upper, lower, 0.0)


def _ground_mesh(area: tuple[float, ...], rng: np.random.Generator) -> trimesh.Trimesh:
    v, f, n = ground_grid(area)
    return _textured(v, f, n, grass_texture(rng, GRASS_PX), GRASS_TILE_M, "ground")


# roadside colours (RGBA)
RAIL = (172, 176, 180, 255)
POST = (120, 122, 126, 255)
KERB = (150, 150, 146, 255)
SIDEWALK = (168, 164, 156, 255)
POLE = (95, 98, 102, 255)
LAMP = (230, 230, 200, 255)
TRUNK = (92, 70, 48, 255)
FOLIAGE = ((46, 86, 40, 255), (60, 100, 44, 255), (38, 70, 36, 255), (74, 104, 52, 255))
BUILDING = ((170, 160, 148), (140, 132, 125), (190, 180, 160), (120, 110, 100), (160, 150, 130))
BARRIER = (230, 120, 30, 255)


def _roadside_mesh(
    geo: RoadGeometry,
    area: tuple[float, ...],
    rng: np.random.Generator,
    urban: object,
) -> trimesh.Trimesh | None:
    parts = _Parts()
    edges = _outer_edges(geo, area, urban)
    rail_profile = np.array([[0.0, 0.45], [0.05, 0.45], [0.05, 0.78], [0.0, 0.78]])
    post_v, post_f, post_n = _box((-0.05, -0.05, 0.0), (0.05, 0.05, 0.75))
    pole_v, pole_f, pole_n = _unmerged(trimesh.creation.cylinder(0.09, 9.0, sections=6))
    pole_v = pole_v + (0, 0, 4.5)
    arm_v, arm_f, arm_n = _box((0.0, -0.06, 8.8), (2.2, 0.06, 8.95))
    lamp_v, lamp_f, lamp_n = _box((1.6, -0.15, 8.65), (2.3, 0.15, 8.8))
    tree_xy: list[np.ndarray] = []
    buildings: list[np.ndarray] = []
    for pts, out_n, is_urban in edges:
        s, left_n = _polyline_frame(pts)
        # the profile is laid out towards the road side's outside: flip to 'left = outward'
        flip = np.sign(np.sum(left_n * out_n, axis=1, keepdims=True))
        side_n = left_n * flip
        if is_urban:
            kerb = np.array([[0.0, 0.0], [0.2, 0.0], [0.2, 0.15], [0.0, 0.15]])
            walk = np.array([[0.2, 0.0], [2.7, 0.0], [2.7, 0.15], [0.2, 0.15]])
            parts.add(*_sweep_oriented(pts, side_n, kerb, flip), np.array(KERB, np.uint8))
            parts.add(*_sweep_oriented(pts, side_n, walk, flip), np.array(SIDEWALK, np.uint8))
            lamp_every, lamp_off = 30.0, 2.4
        else:
            rail_path = pts + 0.6 * out_n
            parts.add(
                *_sweep_oriented(rail_path, side_n, rail_profile, flip), np.array(RAIL, np.uint8)
            )
            at = np.arange(0.0, s[-1], 2.0)
            xy = np.stack([np.interp(at, s, rail_path[:, 0]), np.interp(at, s, rail_path[:, 1])], 1)
            xy += 0.08 * np.stack([np.interp(at, s, out_n[:, 0]), np.interp(at, s, out_n[:, 1])], 1)
            yaw = np.arctan2(np.interp(at, s, out_n[:, 1]), np.interp(at, s, out_n[:, 0]))
            v, f, n = _instances(post_v, post_f, post_n, xy, yaw, np.ones((len(at), 3)))
            parts.add(v, f, n, np.array(POST, np.uint8))
            lamp_every, lamp_off = 50.0, 1.4
        # light poles, the arm reaching over the road
        at = np.arange(rng.uniform(0, lamp_every), s[-1], lamp_every)
        if len(at):
            on = np.stack([np.interp(at, s, out_n[:, 0]), np.interp(at, s, out_n[:, 1])], 1)
            xy = np.stack([np.interp(at, s, pts[:, 0]), np.interp(at, s, pts[:, 1])], 1)
            xy += lamp_off * on
            yaw = np.arctan2(-on[:, 1], -on[:, 0])  # the arm (template +x) points to the road
            one = np.ones((len(at), 3))
            parts.add(*_instances(pole_v, pole_f, pole_n, xy, yaw, one), np.array(POLE, np.uint8))
            parts.add(*_instances(arm_v, arm_f, arm_n, xy, yaw, one), np.array(POLE, np.uint8))
            parts.add(*_instances(lamp_v, lamp_f, lamp_n, xy, yaw, one), np.array(LAMP, np.uint8))
        # trees (and buildings on urban roads) set back from the edge
        n_obj = rng.poisson(s[-1] / (25.0 if is_urban else 10.0))
        at = rng.uniform(0, s[-1], n_obj)
        on = np.stack([np.interp(at, s, out_n[:, 0]), np.interp(at, s, out_n[:, 1])], 1)
        base = np.stack([np.interp(at, s, pts[:, 0]), np.interp(at, s, pts[:, 1])], 1)
        if is_urban:
            depth = rng.uniform(8.0, 16.0, n_obj)
            width = rng.uniform(10.0, 22.0, n_obj)
            height = rng.uniform(6.0, 22.0, n_obj)
            setback = 2.7 + rng.uniform(3.0, 6.0, n_obj) + depth / 2
            c = base + setback[:, None] * on
            yaw = np.arctan2(on[:, 1], on[:, 0])
            buildings.append(np.column_stack([c, yaw, depth, width, height]))
            t_at = rng.uniform(0, s[-1], rng.poisson(s[-1] / 15.0))
            t_on = np.stack([np.interp(t_at, s, out_n[:, 0]), np.interp(t_at, s, out_n[:, 1])], 1)
            t_base = np.stack([np.interp(t_at, s, pts[:, 0]), np.interp(t_at, s, pts[:, 1])], 1)
            tree_xy.append(t_base + 1.6 * t_on)  # street trees on the sidewalk
        else:
            tree_xy.append(base + rng.uniform(4.0, 30.0, n_obj)[:, None] * on)
    # scattered trees over the whole area
    xmin, xmax, ymin, ymax = area
    n_sc = min(int((xmax - xmin) * (ymax - ymin) / 900.0), 400)
    tree_xy.append(np.column_stack([rng.uniform(xmin, xmax, n_sc), rng.uniform(ymin, ymax, n_sc)]))
    if buildings:
        b = np.concatenate(buildings)
        b = b[_footprints_clear(geo, area, b[:, :2], b[:, 2], b[:, 3], b[:, 4], margin=3.5)]
        _add_buildings(parts, b, rng)
    else:
        b = np.zeros((0, 6))
    xy = np.concatenate(tree_xy) if tree_xy else np.zeros((0, 2))
    keep = _in_area(xy, area) & ~geo.contains_xy(xy, margin_m=1.2)
    if len(b):  # no tree inside a building
        keep &= ~_inside_boxes(xy, b[:, :2], b[:, 2], b[:, 3], b[:, 4], margin=1.0)
    _add_trees(parts, xy[keep], rng)
    obs = geo.obstacles_xyyaw_lw
    if len(obs):
        bv, bf, bn = _box((-0.5, -0.5, 0.0), (0.5, 0.5, 1.0))
        scale = np.column_stack([obs[:, 3], obs[:, 4], np.full(len(obs), 1.0)])
        parts.add(
            *_instances(bv, bf, bn, obs[:, :2], obs[:, 2], scale), np.array(BARRIER, np.uint8)
        )
    return parts.mesh("roadside")


def _sweep_oriented(
    path: np.ndarray, side_n: np.ndarray, profile: np.ndarray, flip: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """_sweep with 'lateral' = side_n; keeps outward normals when side_n is a right normal."""
    v, f, n = _sweep(path, side_n, profile)
    if np.mean(flip) < 0:  # side_n is the path's right normal: mirrored profile, flip winding
        f = f[:, ::-1]
    return v, f, n


def _outer_edges(
    geo: RoadGeometry, area: tuple[float, ...], urban: object
) -> list[tuple[np.ndarray, np.ndarray, bool]]:
    """Runs of lane edges with a continuous line and no road beyond them.

    Returns (points (N, 2), outward unit normals (N, 2), urban?) per run; the points
    are on the outside of the shoulder.
    """
    out = []
    for lane in geo.lanes:
        nl = _left_normals(lane)
        for side, edge, sign in ((0, lane.left_xy, 1.0), (1, lane.right_xy, -1.0)):
            if lane.line_types[side] < CONTINUOUS:
                continue
            on = sign * nl
            rim = edge + (SHOULDER_M + LANE_OVERLAP_M) * on
            probe = np.concatenate([edge + 0.8 * on, rim + 1.0 * on])
            hit = geo.contains_xy(probe, margin_m=0.0).reshape(2, -1).any(axis=0)
            ok = ~hit & _in_area(rim, area)
            for a, b in _runs(ok):
                if b - a >= 3:
                    out.append((rim[a:b], on[a:b], bool(urban(lane))))
    return out


def _in_area(xy: np.ndarray, area: tuple[float, ...]) -> np.ndarray:
    return (
        (xy[:, 0] >= area[0])
        & (xy[:, 0] <= area[1])
        & (xy[:, 1] >= area[2])
        & (xy[:, 1] <= area[3])
    )


def _box_corners(
    c: np.ndarray, yaw: np.ndarray, depth: np.ndarray, width: np.ndarray
) -> np.ndarray:
    """(M, 4, 2) corners of boxes (depth along yaw, width across)."""
    u = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    w = np.stack([-u[:, 1], u[:, 0]], axis=1)
    sx = np.array([1, 1, -1, -1])[None, :, None] * (depth / 2)[:, None, None]
    sy = np.array([1, -1, -1, 1])[None, :, None] * (width / 2)[:, None, None]
    return c[:, None, :] + sx * u[:, None, :] + sy * w[:, None, :]


def _footprints_clear(
    geo: RoadGeometry,
    area: tuple[float, ...],
    c: np.ndarray,
    yaw: np.ndarray,
    depth: np.ndarray,
    width: np.ndarray,
    margin: float,
) -> np.ndarray:
    """(M,) True where a box (and its centre) stays off the road and inside the area."""
    if len(c) == 0:
        return np.zeros(0, bool)
    corners = _box_corners(c, yaw, depth, width)
    pts = np.concatenate([corners, c[:, None, :]], axis=1).reshape(-1, 2)
    hit = geo.contains_xy(pts, margin_m=margin).reshape(len(c), 5).any(axis=1)
    return ~hit & _in_area(c, area)


def _inside_boxes(
    xy: np.ndarray,
    c: np.ndarray,
    yaw: np.ndarray,
    depth: np.ndarray,
    width: np.ndarray,
    margin: float,
) -> np.ndarray:
    d = xy[:, None, :] - c[None, :, :]
    u = np.stack([np.cos(yaw), np.sin(yaw)], axis=1)
    a = np.abs(np.einsum("mbk,bk->mb", d, u))
    b = np.abs(d[..., 0] * -u[None, :, 1] + d[..., 1] * u[None, :, 0])
    return np.any((a <= depth / 2 + margin) & (b <= width / 2 + margin), axis=1)


def _add_buildings(parts: _Parts, b: np.ndarray, rng: np.random.Generator) -> None:
    if len(b) == 0:
        return
    bv, bf, bn = _box((-0.5, -0.5, 0.0), (0.5, 0.5, 1.0))
    scale = b[:, [3, 4, 5]]
    v, f, n = _instances(bv, bf, bn, b[:, :2], b[:, 2], scale)
    pal = np.array(BUILDING, float)[rng.integers(0, len(BUILDING), len(b))]
    pal *= rng.uniform(0.9, 1.1, (len(b), 1))
    col = np.repeat(pal, len(bv), axis=0)
    col[np.isclose(n[:, 2], 1.0)] *= 0.6  # darker flat roofs
    rgba = np.column_stack([np.clip(col, 0, 255), np.full(len(col), 255.0)]).astype(np.uint8)
    parts.add(v, f, n, rgba)
    # window bands: thin dark boxes slightly proud of the two long facades
    floors = np.floor((b[:, 5] - 1.0) / 3.2).astype(int)
    rows = [(i, k) for i in range(len(b)) for k in range(floors[i])]
    if not rows:
        return
    idx = np.array([r[0] for r in rows])
    z = np.array([r[1] for r in rows]) * 3.2 + 1.2
    wv, wf, wn = _box((-0.51, -0.45, 0.0), (0.51, 0.45, 1.0))
    scale = np.column_stack([b[idx, 3], b[idx, 4], np.full(len(idx), 1.4)])
    v, f, n = _instances(wv, wf, wn, b[idx, :2], b[idx, 2], scale, z=z)
    parts.add(v, f, n, np.array((48, 56, 66, 255), np.uint8))


def _add_trees(parts: _Parts, xy: np.ndarray, rng: np.random.Generator) -> None:
    m = len(xy)
    if m == 0:
        return
    h = rng.uniform(4.0, 12.0, m)
    tv, tf, tn = _unmerged(trimesh.creation.cylinder(0.5, 1.0, sections=6))
    tv = tv + (0, 0, 0.5)
    trunk_h = 0.35 * h
    r = rng.uniform(0.12, 0.25, m)
    scale = np.column_stack([2 * r, 2 * r, trunk_h])
    parts.add(*_instances(tv, tf, tn, xy, np.zeros(m), scale), np.array(TRUNK, np.uint8))
    conifer = rng.uniform(size=m) < 0.5
    cv, cf, cn = _unmerged(trimesh.creation.cone(1.0, 1.0, sections=8))
    bv, bf, bn = _unmerged(trimesh.creation.icosphere(subdivisions=1, radius=0.5))
    bv = bv + (0, 0, 0.5)
    # conifers: a cone of radius 0.3 x its height; broadleaves: a ball 0.6 x as wide
    for sel, (v0, f0, n0), xy_scale, z_frac in (
        (conifer, (cv, cf, cn), 0.3, 0.6),
        (~conifer, (bv, bf, bn), 0.6, 0.8),
    ):
        k = int(sel.sum())
        if k == 0:
            continue
        hh = h[sel] * 0.75
        scale = np.column_stack([xy_scale * hh, xy_scale * hh, hh])
        z = trunk_h[sel] * z_frac
        v, f, n = _instances(v0, f0, n0, xy[sel], rng.uniform(0, 2 * np.pi, k), scale, z=z)
        pal = np.array(FOLIAGE, np.uint8)[rng.integers(0, len(FOLIAGE), k)]
        parts.add(v, f, n, np.repeat(pal, len(v0), axis=0))


# --------------------------------------------------------------------------- vehicles

# Reference car (metres) the template is built for; each vehicle scales it to its box.
_REF_L, _REF_W, _REF_H = 5.0, 2.0, 1.5
BODY, GLASS, TYRE, HEADLIGHT, TAILLIGHT = range(5)


def _car_template() -> tuple[np.ndarray, ...]:
    """(V, 3) vertices, (F, 3) faces, (V, 3) normals, (V,) part roles of the car, and
    (V,) the convex solid each vertex belongs to (0: lower body and lights; 1: hood rise;
    2: greenhouse; 3-6: the wheels): the car is the union of their convex hulls, with the
    gap under the body open."""
    parts: list[tuple[np.ndarray, ...]] = []

    def add(vfn: tuple[np.ndarray, ...], role: np.ndarray | int, solid: int = 0) -> None:
        v, f, n = vfn
        r = np.broadcast_to(np.asarray(role), (len(v),)).copy()
        parts.append((v, f, n, r, np.full(len(v), solid)))

    hl, hw = _REF_L / 2, _REF_W / 2
    add(_box((-hl, -hw + 0.03, 0.16), (hl, hw - 0.03, 0.80)), BODY)  # lower body
    add(_box((hl - 1.15, -hw + 0.06, 0.80), (hl, hw - 0.06, 0.88)), BODY, 1)  # hood rise
    # greenhouse: a frustum; roof in body colour, the four sloped sides are glass
    lo = np.array([[-1.85, -0.9], [1.05, -0.9], [1.05, 0.9], [-1.85, 0.9]])
    hi = np.array([[-1.25, -0.76], [0.25, -0.76], [0.25, 0.76], [-1.25, 0.76]])
    pts = np.vstack(
        [np.column_stack([lo, np.full(4, 0.80)]), np.column_stack([hi, np.full(4, _REF_H)])]
    )
    v, f, n = _unmerged(trimesh.convex.convex_hull(pts))
    add((v, f, n), np.where(n[:, 2] > 0.99, BODY, GLASS), 2)
    # wheels: octagonal prisms, axis along y, touching the road
    cyl = trimesh.creation.cylinder(0.34, 0.24, sections=8)
    cyl.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, (1, 0, 0)))
    wv, wf, wn = _unmerged(cyl)
    wv = wv - (0.0, 0.0, wv[:, 2].min())  # the lowest tread vertex touches the road
    for k, (x, y) in enumerate([(x, y) for x in (-1.6, 1.6) for y in (-hw + 0.12, hw - 0.12)]):
        add((wv + (x, y, 0.0), wf, wn), TYRE, 3 + k)
    for y0, y1 in ((-0.85, -0.5), (0.5, 0.85)):
        add(_box((hl - 0.01, y0, 0.58), (hl + 0.02, y1, 0.70)), HEADLIGHT)
        add(_box((-hl - 0.02, y0, 0.62), (-hl + 0.01, y1, 0.74)), TAILLIGHT)
    fs, base = [], 0
    for p in parts:
        fs.append(p[1] + base)
        base += len(p[0])
    v, n, r, solid = (np.concatenate([p[k] for p in parts]) for k in (0, 2, 3, 4))
    return v, np.concatenate(fs), n, r, solid


_CAR = _car_template()
_CAR_CORNERS = _CAR[0][_CAR[1]].reshape(-1, 3)  # (3F, 3) the template's triangle corners
# (K, 3) corners of the hulls of its convex solids, padded by repeating a corner
_CAR_SOLIDS = [
    trimesh.convex.convex_hull(_CAR[0][_CAR[4] == k]).vertices for k in range(_CAR[4].max() + 1)
]
_CAR_SOLID_PTS = np.stack(
    [np.vstack([h, np.repeat(h[:1], max(map(len, _CAR_SOLIDS)) - len(h), 0)]) for h in _CAR_SOLIDS]
)

# body colours (RGB) in rough proportion to what is seen on roads
CAR_PALETTE = np.array(
    [
        (225, 226, 222),
        (225, 226, 222),
        (172, 174, 178),
        (172, 174, 178),
        (108, 110, 114),
        (28, 29, 32),
        (28, 29, 32),
        (32, 46, 92),
        (150, 24, 26),
        (44, 84, 152),
        (190, 176, 142),
        (42, 82, 52),
        (204, 170, 40),
        (200, 100, 32),
    ],
    dtype=float,
)
_ROLE_RGB = {
    GLASS: (36, 44, 54),
    TYRE: (22, 22, 24),
    HEADLIGHT: (240, 238, 215),
    TAILLIGHT: (175, 20, 22),
}


def body_color(vehicle_id: int) -> np.ndarray:
    """Deterministic body colour (3,) uint8 of a vehicle id."""
    h = (int(vehicle_id) * 2654435761 + 0x9E3779B9) & 0xFFFFFFFF
    rgb = CAR_PALETTE[(h >> 8) % len(CAR_PALETTE)] * (0.92 + 0.16 * ((h >> 20) & 0xFF) / 255.0)
    return np.clip(np.round(rgb), 0, 255).astype(np.uint8)


def id_color(vehicle_id: int | np.ndarray) -> np.ndarray:
    """(..., 3) uint8 RGB encoding ``id + 1`` in 24 bits (R low byte, B high byte)."""
    value = np.asarray(vehicle_id, dtype=np.int64) + 1
    if np.any(value < 1) or np.any(value >= 1 << 24):
        raise ValueError(f"vehicle ids must be in [0, 2**24 - 2], got {vehicle_id!r}")
    return np.stack([value & 255, (value >> 8) & 255, value >> 16], axis=-1).astype(np.uint8)


def decode_id_image(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 id render -> (H, W) int32 vehicle id, -1 where no vehicle."""
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] < 3 or rgb.dtype != np.uint8:
        raise ValueError(f"expected an (H, W, 3) uint8 image, got {rgb.shape} {rgb.dtype}")
    v = (
        rgb[..., 0].astype(np.int32)
        | (rgb[..., 1].astype(np.int32) << 8)
        | (rgb[..., 2].astype(np.int32) << 16)
    )
    return v - 1


def _posed_cars(
    vehicles: Sequence[VehicleState],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The car template scaled to each vehicle's length/width/height and posed by (x, y,
    yaw), in one numpy operation: (M*V, 3) vertices, (M*F, 3) faces, (M*V, 3) normals
    and (M,) int64 ids of the M vehicles."""
    tv, tf, tn = _CAR[:3]
    xy, yaw, scale, ids = _vehicle_poses(vehicles)
    verts, faces, norms = _instances(tv, tf, tn, xy, yaw, scale)
    return verts, faces, norms, ids


def _vehicle_poses(
    vehicles: Sequence[VehicleState],
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(M, 2) x, y [m], (M,) yaw [rad], (M, 3) the car template's scale to each vehicle's
    length, width and height, and (M,) int64 ids of the vehicles."""
    arr = np.array(
        [(v.x_m, v.y_m, v.yaw_rad, v.length_m, v.width_m, v.height_m, v.id) for v in vehicles],
        dtype=float,
    )
    scale = arr[:, 3:6] / np.array([_REF_L, _REF_W, _REF_H])
    return arr[:, :2], arr[:, 2], scale, arr[:, 6].astype(np.int64)


def _role_colors(ids: np.ndarray, roles: np.ndarray) -> np.ndarray:
    """(M * len(roles), 3) uint8 colours of the template's parts (roles: one per vertex or
    per face) for vehicles ids (M,): the body colour of the id, dark glass and tyres,
    lights."""
    per = np.zeros((len(ids), len(roles), 3), np.uint8)
    per[:] = np.stack([body_color(i) for i in ids])[:, None, :]
    for role, c in _ROLE_RGB.items():
        per[:, roles == role] = c
    return per.reshape(-1, 3)


def vehicles_mesh(vehicles: Sequence[VehicleState], mode: str = "color") -> trimesh.Trimesh | None:
    """ALL vehicles as ONE mesh (None if there are none).

    mode: ``"color"`` (body colour from the id, dark glass and tyres, lights) or
    ``"id"`` (every vertex of vehicle ``id`` coloured :func:`id_color`; render FLAT).
    The template is scaled to each vehicle's length/width/height and posed by
    (x, y, yaw) in one numpy operation.
    """
    if mode not in VEHICLE_MODES:
        raise ValueError(f"mode must be one of {VEHICLE_MODES}, got {mode!r}")
    if len(vehicles) == 0:
        return None
    roles = _CAR[3]
    verts, faces, norms, ids = _posed_cars(vehicles)
    nv = len(roles)
    rgb = np.repeat(id_color(ids), nv, axis=0) if mode == "id" else _role_colors(ids, roles)
    rgba = np.column_stack([rgb, np.full(len(rgb), 255, np.uint8)])
    m = trimesh.Trimesh(
        vertices=verts, faces=faces, vertex_normals=norms, vertex_colors=rgba, process=False
    )
    m.metadata["name"] = f"vehicles_{mode}"
    m.metadata["vertices_per_vehicle"] = nv
    return m


def vehicle_triangles(
    vehicles: Sequence[VehicleState],
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Every vehicle's triangles, as `vehicles_mesh` builds them, without a mesh object.

    Returns (T, 3, 3) corners [m] (world), (T, 3) uint8 albedo of each triangle (its
    colour in ``mode="color"``) and (T,) int64 vehicle id; each vehicle has the same
    number of triangles, in the order of ``vehicles``.
    """
    if len(vehicles) == 0:
        return np.zeros((0, 3, 3)), np.zeros((0, 3), np.uint8), np.zeros(0, np.int64)
    tf, roles = _CAR[1], _CAR[3]
    xy, yaw, scale, ids = _vehicle_poses(vehicles)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    corners = _posed_points(_CAR_CORNERS, xy, c, s, scale).reshape(-1, 3, 3)
    albedo = _role_colors(ids, roles[tf[:, 0]])  # a face's role: its first vertex's
    return corners, albedo, np.repeat(ids, len(tf))


def vehicle_solids(vehicles: Sequence[VehicleState]) -> np.ndarray:
    """(M, S, K, 3) corners [m] (world) of the S convex solids whose union is each
    vehicle, as `vehicles_mesh` poses the template."""
    xy, yaw, scale, _ = _vehicle_poses(vehicles)
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    S, K = _CAR_SOLID_PTS.shape[:2]
    return _posed_points(_CAR_SOLID_PTS.reshape(-1, 3), xy, c, s, scale).reshape(-1, S, K, 3)


def vehicle_corners_world(v: VehicleState) -> np.ndarray:
    """(8, 3) corners of the vehicle's bounding box in the world [m].

    Order: front-left, front-right, rear-right, rear-left at z = 0, then the same at
    z = height_m ("front" = +length/2 along the yaw, "left" = +width/2).
    """
    c, s = np.cos(v.yaw_rad), np.sin(v.yaw_rad)
    lx = np.array([1, 1, -1, -1]) * v.length_m / 2
    ly = np.array([1, -1, -1, 1]) * v.width_m / 2
    x = v.x_m + c * lx - s * ly
    y = v.y_m + s * lx + c * ly
    bottom = np.column_stack([x, y, np.zeros(4)])
    top = np.column_stack([x, y, np.full(4, v.height_m)])
    return np.vstack([bottom, top])


def id_occluder_mesh(meshes: Sequence[trimesh.Trimesh]) -> trimesh.Trimesh | None:
    """The static meshes merged into one black (id 0 = "no vehicle") mesh for the id pass."""
    meshes = [m for m in meshes if m is not None and len(m.faces)]
    if not meshes:
        return None
    parts = _Parts()
    for m in meshes:
        parts.add(m.vertices, m.faces, m.vertex_normals, np.array((0, 0, 0, 255), np.uint8))
    return parts.mesh("id_occluder")
