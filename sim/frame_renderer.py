"""What one camera sees of the world at one instant, before sensor effects.

Two ways to render a frame, with the same outputs (`FrameImages`):

- `PlaneFrameRenderer` (the default): the road plane (road, markings, grass) is drawn
  analytically for every pixel (`sim.ground`), in the vehicles' shadows if asked
  (`sim.shadows`); only what stands on it (vehicles, guard-rails, posts, trees,
  buildings) is rasterised by pyrender into the windows of cube faces that valid pixels
  see (`sim.renderer`), and laid over the plane by its coverage (whatever a ray hits
  above the plane is nearer than the plane).
- `CubeFrameRenderer`: everything rasterised into cube faces and ray-mapped, the plane
  included, without shadows (kept to measure against: `scenarios.motion_fidelity`).

Both draw the pixels of the car body under an omni mirror once, at the first frame.
"""

from __future__ import annotations

from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import cv2
import numpy as np
from numba import njit, prange

from estimator.camera.models import CameraModel
from estimator.frame_times import StageClock
from sim.coded_scene import (
    AMBIENT,
    SUN_INTENSITY,
    SUN_TOWARDS,
    CodedScene,
    decode,
    premultiplied_rgba,
)
from sim.gl import pyrender, set_depth_offset
from sim.ground import CoverageMap, GroundLook, GroundRenderer, MipTexture
from sim.highway import VehicleState
from sim.renderer import OmniRenderer, finest_pixel_angle_rad
from sim.scene import DEPTH_OFFSET, WHITE, decode_id_image, id_occluder_mesh, vehicles_mesh
from sim.shadows import cast_shadows

SKY_RGB = (0.62, 0.74, 0.90)
RENDERERS = ("plane", "cube")  # `PlaneFrameRenderer`, `CubeFrameRenderer`
PLANE_MESHES = ("road", "markings", "ground")  # `sim.scene.build_static_scene` names
# irradiance factor of the plane's materials [-] (`sim.ground.GroundLook`): least-squares
# fits to the cube renderer's pixels of each material (pyrender's shading of the same
# surfaces under the scene's sun and ambient light); highway-v0, omni-near and omni-far
# agree to 0.5 % (docs/DESIGN.md)
PLANE_K = {"road": 0.266, "grass": 0.451, "markings": 0.826}
OBJECT_OVERSAMPLING = 1.0  # [-] face texels per camera pixel for what stands on the road, 0.5..2
BODY_MARGIN_PX = 3  # [px] the body's pixels kept from the first frame are this far inside it


@dataclass
class FrameImages:
    """One rendered frame: image (H, W, 3) uint8, ids (H, W) int32 (-1 none), range_m (H, W)."""

    image: np.ndarray
    ids: np.ndarray
    range_m: np.ndarray


# A camera pixel is a bilinear lookup into a cube face (`sim.renderer`). Where the face
# samples the view more coarsely than the camera (at the face centre, its coarsest), the
# image is an upsampling of the face, and its texture (filtered, aliased) on the face's
# grid: a pattern fixed to the camera, which pulls the motion seen in the images towards
# zero. Faces at least this many times finer than the camera's finest pixel keep the
# camera's sampling in charge (and `sim.renderer.prefilter_sigma_px` low-passes them back
# to the camera's pixel). Measured on racetrack-omni-near frames 24-60: 512 px faces
# (0.8x) speed 1.85 % / yaw bias -0.78 deg/s, 1024 px (1.6x) 0.90 % / -0.63 deg/s.
FACE_OVERSAMPLING = 1.5
MAX_FACE_PX = 2048


def default_face_px(camera: CameraModel) -> int:
    """Cube-face size [px] (a power of two, 128..MAX_FACE_PX) whose texels at the face
    centre are FACE_OVERSAMPLING times finer than the camera's finest pixels."""
    finest_rad = finest_pixel_angle_rad(camera)
    # face focal length (face_px - 3) / 2 [px per unit tan] (`CubeMapLookup.build`)
    need = 2.0 * FACE_OVERSAMPLING / np.tan(finest_rad) + 3.0
    return int(np.clip(2 ** np.ceil(np.log2(need)), 128, MAX_FACE_PX))


def static_pyrender_mesh(mesh) -> pyrender.Mesh:
    """pyrender mesh of a static scene mesh, drawn with the depth offset of its surface
    (`sim.scene.DEPTH_OFFSET`: road, grass and markings share one plane)."""
    m = pyrender.Mesh.from_trimesh(mesh, smooth=False)
    return set_depth_offset(m, DEPTH_OFFSET.get(mesh.metadata.get("name"), 0.0))


class WorldScenes:
    """pyrender colour and id scenes of one drive: static world + per-frame vehicles."""

    def __init__(self, static_meshes: list, id_static: list) -> None:
        self.color = pyrender.Scene(bg_color=[*SKY_RGB, 1.0], ambient_light=[AMBIENT] * 3)
        self.ids = pyrender.Scene(bg_color=[0, 0, 0, 1.0], ambient_light=[1.0, 1.0, 1.0])
        for m in static_meshes:
            self.color.add(static_pyrender_mesh(m))
        for m in id_static:
            self.ids.add(pyrender.Mesh.from_trimesh(m, smooth=False))
        sun = pyrender.DirectionalLight(color=np.ones(3), intensity=SUN_INTENSITY)
        self.color.add(sun, pose=_look_pose(SUN_TOWARDS))
        self._veh_nodes: list = []

    def set_vehicles(self, vehicles: Sequence[VehicleState]) -> None:
        for scene, node in self._veh_nodes:
            scene.remove_node(node)
        self._veh_nodes = []
        for scene, mode in ((self.color, "color"), (self.ids, "id")):
            mesh = vehicles_mesh(vehicles, mode=mode)
            if mesh is not None:
                node = scene.add(pyrender.Mesh.from_trimesh(mesh, smooth=False))
                self._veh_nodes.append((scene, node))


def _look_pose(direction: np.ndarray) -> np.ndarray:
    """Pose whose -z axis points along ``direction`` (for a directional light)."""
    z = -direction / np.linalg.norm(direction)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    T = np.eye(4)
    T[:3, :3] = np.stack([x, y, z], axis=1)
    return T


def object_face_px(camera: CameraModel) -> int:
    """Cube-face size [px] (a multiple of 8, 64..MAX_FACE_PX) whose texels at the face
    centre are OBJECT_OVERSAMPLING times finer than the camera's finest pixels."""
    need = 2.0 * OBJECT_OVERSAMPLING / np.tan(finest_pixel_angle_rad(camera)) + 3.0
    return int(np.clip(8 * np.ceil(need / 8), 64, MAX_FACE_PX))


class CubeFrameRenderer:
    """Everything, the road plane included, rasterised into cube faces and ray-mapped."""

    def __init__(self, camera: CameraModel, static_meshes: list, face_px: int | None = None):
        self.camera = camera
        self.face_px = face_px or default_face_px(camera)
        occluder = id_occluder_mesh(static_meshes)
        self.scenes = WorldScenes(static_meshes, [] if occluder is None else [occluder])
        self._renderer = OmniRenderer(camera, self.face_px)
        self.clock = StageClock()

    def settings(self) -> dict:
        return {"renderer": "cube", "face_px": self.face_px}

    def start(self, vehicles: Sequence[VehicleState], T_world_cam: np.ndarray) -> None:
        """Render the faces that only show the car body, once, at this frame."""
        self.scenes.set_vehicles(vehicles)
        self._renderer.keep_body_faces(self.scenes.color, T_world_cam)
        self._renderer.keep_body_faces(self.scenes.ids, T_world_cam, flat=True)

    def render(self, vehicles: Sequence[VehicleState], T_world_cam: np.ndarray) -> FrameImages:
        r, clock = self._renderer, self.clock
        self.scenes.set_vehicles(vehicles)
        clock.lap("vehicles")
        atlas, _ = r.render_atlas(self.scenes.color, T_world_cam)
        # depth from the id scene: the same surfaces, without the colour scene's depth
        # offsets (`sim.scene.DEPTH_OFFSET`), which push far grass back by metres
        id_atlas, depth = r.render_atlas(self.scenes.ids, T_world_cam, flat=True, depth=True)
        clock.lap("faces_gl")
        out = FrameImages(
            r.remap_color(atlas), decode_id_image(r.remap_nearest(id_atlas)), r.range_image(depth)
        )
        clock.lap("ray_map")
        return out

    def close(self) -> None:
        self._renderer.close()


class PlaneFrameRenderer:
    """The road plane drawn analytically, what stands on it rasterised over it.

    T_world_cam_ref: a nominal pose of the camera on its car (its height and tilt above
    the plane set the pixels' footprints, `sim.ground`); face_px: cube-face size of the
    objects' faces (default `object_face_px`); cache_body: draw the car body's pixels
    once (`start`), for a camera that stays on one car; static_meshes, area_xy: the
    static world (`set_static`); shadows: the vehicles cast shadows on the plane
    (`sim.shadows`).
    """

    def __init__(
        self,
        camera: CameraModel,
        T_world_cam_ref: np.ndarray,
        face_px: int | None = None,
        cache_body: bool = True,
        static_meshes: list | None = None,
        area_xy: tuple | None = None,
        shadows: bool = False,
    ) -> None:
        self.camera = camera
        self.shadows = shadows
        self.face_px = face_px or object_face_px(camera)
        self.cache_body = cache_body
        self.scenes = CodedScene([])
        self.look: GroundLook | None = None
        self._look_key: tuple | None = None
        self.coverage: CoverageMap | None = None
        self.T_ref = np.asarray(T_world_cam_ref, float)
        self.imaged = imaged_mask(camera)
        self.sky = np.float32(255.0) * np.asarray(SKY_RGB, np.float32)
        self.body = np.zeros(self.imaged.shape, bool)
        self._objects: OmniRenderer | None = None
        self._ground: GroundRenderer | None = None
        self._pool = ThreadPoolExecutor(max_workers=1)
        self.clock = StageClock()
        if static_meshes is not None:
            self.set_static(static_meshes, area_xy)

    def settings(self) -> dict:
        return {"renderer": "plane", "face_px": self.face_px}

    def set_static(self, static_meshes: list, area_xy: tuple, same_world: bool = False) -> None:
        """The static world: `sim.scene.build_static_scene`'s meshes (road, markings and
        ground: the plane; the rest: objects) covering area_xy (xmin, xmax, ymin, ymax) [m].
        same_world: another window of the world given last (the same road, a window moved
        with the camera): the fine coverage tiles built so far are kept."""
        by_name = {m.metadata.get("name"): m for m in static_meshes}
        self.scenes.set_static(
            [m for m in static_meshes if m.metadata.get("name") not in PLANE_MESHES]
        )
        key = _texture_key(by_name)
        if key != self._look_key:
            self.look, self._look_key = plane_look(by_name), key
        self.coverage = CoverageMap(
            _triangles_xy(by_name.get("road")),
            _triangles_xy(by_name.get("markings")),
            area_xy,
            tiles_from=self.coverage if same_world else None,
        )
        if self._ground is not None:
            self._ground.set_plane(self.look, self.coverage)

    def start(self, vehicles: Sequence[VehicleState], T_world_cam: np.ndarray) -> None:
        """Set up the per-frame renderers. With ``cache_body``, draw the car body's pixels
        once, at this frame: the pixels where the camera's own car (``is_ego``) is seen,
        BODY_MARGIN_PX inside its outline, and those of the cube faces that no valid
        pixel looks up (under an omni mirror: the face below, the roof and a little road
        behind the car, as `CubeFrameRenderer` keeps them)."""
        if self.coverage is None:
            raise RuntimeError("PlaneFrameRenderer.set_static() first")
        if self.cache_body:
            full = OmniRenderer(self.camera, self.face_px, cache_body_faces=False)
            try:
                seen = self._render_with(full, vehicles, T_world_cam, plane=None)
            finally:
                full.close()
            own_id = next(v.id for v in vehicles if v.is_ego)
            k = 2 * BODY_MARGIN_PX + 1
            own = (seen.ids == own_id).astype(np.uint8)
            body = cv2.erode(own, np.ones((k, k), np.uint8)) > 0
            for face in full.lookup.face_masks():
                if not np.any(face & self.camera.valid_mask()):
                    body |= face
            self.body = body & self.imaged
            self.body_images = seen  # read where self.body is set
        pixels = self.imaged & ~self.body
        self._objects = OmniRenderer(
            self.camera, self.face_px, pixels=pixels, windowed=True, cache_body_faces=False
        )
        self._ground = GroundRenderer(
            self.camera, self.T_ref, self.look, self.coverage, self.sky, pixels=pixels
        )

    def render(self, vehicles: Sequence[VehicleState], T_world_cam: np.ndarray) -> FrameImages:
        """What the camera at T_world_cam (4, 4) sees of the static world and of the
        vehicles (the camera's own car among them, ``is_ego``)."""
        if self._objects is None:
            self.start(vehicles, T_world_cam)
        out = self._render_with(self._objects, vehicles, T_world_cam, plane=self._ground)
        if self.cache_body:
            body, kept = self.body.view(np.uint8), self.body_images
            cv2.copyTo(kept.image, body, out.image)
            cv2.copyTo(kept.ids, body, out.ids)
            cv2.copyTo(kept.range_m, body, out.range_m)
        return out

    def _render_with(self, r: OmniRenderer, vehicles, T_world_cam, plane) -> FrameImages:
        coded, clock = self.scenes, self.clock
        H, W = self.camera.height, self.camera.width
        behind = np.empty((H, W, 3), np.float32)
        behind[:] = self.sky
        range_m = np.full((H, W), np.inf, np.float32)
        # the plane (a kernel that releases the GIL) is drawn while GL draws the objects
        job = (
            None
            if plane is None
            else self._pool.submit(
                _draw_plane, plane, vehicles if self.shadows else (), T_world_cam, behind, range_m
            )
        )
        coded.set_vehicles(vehicles)
        clock.lap("vehicles")
        atlas, depth = r.render_atlas(coded.scene, T_world_cam, flat=True, depth=True)
        clock.lap("objects_gl")
        if job is not None:
            job.result()
        clock.lap("plane_after_gl")
        # objects premultiplied by their coverage, so that their edges blend over the plane
        obj = r.remap_color(premultiplied_rgba(atlas, coded.rgb))
        objects_range = r.range_image(depth)
        seen = np.isfinite(objects_range)
        range_m[seen] = objects_range[seen]
        ids = coded.ids[decode(r.remap_nearest(atlas))]
        out = FrameImages(_over(obj, behind), ids, range_m)
        clock.lap("composite")
        return out

    def close(self) -> None:
        if self._objects is not None:
            self._objects.close()
            self._objects = None
        self._ground = None
        self._pool.shutdown()


def _draw_plane(plane: GroundRenderer, casters, T_world_cam, image, range_m) -> None:
    """The plane, in the shadows of the vehicles casters (none: fully lit), into image
    and range_m (`GroundRenderer.render_into`)."""
    light = cast_shadows(casters, np.asarray(T_world_cam, float)[:2, 3]) if casters else None
    plane.render_into(T_world_cam, image, range_m, light)


def _texture_key(by_name: dict) -> tuple:
    """What identifies the plane's textures (the images' bytes)."""
    return tuple(
        hash(by_name[n].visual.material.image.tobytes()) if n in by_name else None
        for n in ("road", "ground")
    )


@njit(parallel=True, cache=True)
def _over(obj: np.ndarray, behind: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8: premultiplied colour and coverage obj (H, W, 4) uint8 over the
    colour behind (H, W, 3) float32 [DN]."""
    H, W = obj.shape[0], obj.shape[1]
    out = np.empty((H, W, 3), np.uint8)
    for r in prange(H):
        for c in range(W):
            keep = 1.0 - obj[r, c, 3] / 255.0
            for k in range(3):
                v = obj[r, c, k] + keep * behind[r, c, k]
                out[r, c, k] = np.uint8(min(max(np.rint(v), 0.0), 255.0))
    return out


def plane_look(by_name: dict) -> GroundLook:
    """The plane's textures and colours from the static scene's meshes."""

    def texture(name: str) -> MipTexture:
        m = by_name[name]
        image = np.asarray(m.visual.material.image.convert("RGB"))
        return MipTexture(image, m.metadata["tile_m"], srgb=True)  # as pyrender reads it

    return GroundLook(
        asphalt=texture("road") if "road" in by_name else texture("ground"),
        grass=texture("ground"),
        # vertex colours: pyrender uses them as linear values
        marking_albedo=np.asarray(WHITE[:3], np.float32) / 255.0,
        k_road=PLANE_K["road"],
        k_grass=PLANE_K["grass"],
        k_marking=PLANE_K["markings"],
    )


def _triangles_xy(mesh) -> list[np.ndarray]:
    """(3, 2) plane triangles of a mesh in the plane (none without a mesh)."""
    if mesh is None:
        return []
    return list(np.asarray(mesh.vertices)[np.asarray(mesh.faces)][:, :, :2])


def imaged_mask(camera: CameraModel) -> np.ndarray:
    """(H, W) bool: pixels that have an image: the valid field of view plus, for an
    omni camera, the car-body disc in the centre (black beyond the mirror's rim)."""
    mask = camera.valid_mask().copy()
    body_deg = getattr(camera, "body_mask_deg", None)
    if body_deg is not None:
        rays = camera.pixel_rays()
        with np.errstate(invalid="ignore"):
            mask |= rays[..., 2] > np.cos(np.radians(body_deg))  # Z down: angle from nadir
    return mask
