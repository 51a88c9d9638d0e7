"""Omni (and pinhole) images by ray-mapping a cube map rendered with pyrender.

The mirror has a single viewpoint, so the image is a function of the ray
directions through it: pyrender renders the faces of a cube map at the
viewpoint, oriented with the *actual* camera axes; every camera pixel's ray
(``camera.pixel_rays()``, eq. 9-10) picks a face and a texel. That lookup
depends only on the camera, so it is computed once (`CubeMapLookup`) and each
frame costs the face renders and one ``cv2.remap`` per channel group.

Faces are rendered with 1.5 px of margin beyond 90 degrees so that bilinear
interpolation never reads across a face border. Only faces that some valid
pixel sees are rendered.

Outputs per frame: RGB image (H, W, 3) uint8, vehicle-id image (H, W) int32
(-1 = no vehicle), range image (H, W) float32 metres along the ray (inf = sky).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from estimator.camera.models import CameraModel
from estimator.synthetic import pixel_angle_rad
from sim.gl import pyrender

# Face directions in camera coordinates and an "up" vector for each (GL y).
_FACE_DIRS = {
    "+x": ((1, 0, 0), (0, 0, -1)),
    "-x": ((-1, 0, 0), (0, 0, -1)),
    "+y": ((0, 1, 0), (0, 0, -1)),
    "-y": ((0, -1, 0), (0, 0, -1)),
    "+z": ((0, 0, 1), (0, 1, 0)),
    "-z": ((0, 0, -1), (0, 1, 0)),
}


def face_rotation(name: str) -> np.ndarray:
    """(3, 3) R_cam_face: columns are the GL face camera's x, y, z axes in camera coords.

    A GL camera looks along its -z axis with y up.
    """
    look, up = (np.asarray(v, dtype=float) for v in _FACE_DIRS[name])
    z = -look
    y = up - np.dot(up, z) * z
    y /= np.linalg.norm(y)
    x = np.cross(y, z)
    return np.stack([x, y, z], axis=1)


@dataclass
class CubeMapLookup:
    """Per-pixel cube-map lookup of a camera, computed once.

    faces: names of the faces to render, in atlas order.
    face_px: side of a face image [px]; focal_px: its focal length [px].
    map1, map2: fixed-point maps for ``cv2.remap`` into the face atlas
        (faces stacked vertically, each ``face_px`` tall).
    cos_to_axis: (H, W) float32, -d_face_z of each pixel's unit ray: converts the
        rendered z-depth to range along the ray.
    valid: (H, W) bool, pixels with a valid ray.
    """

    faces: list[str]
    face_px: int
    focal_px: float
    map_x: np.ndarray
    map_y: np.ndarray
    map1: np.ndarray
    map2: np.ndarray
    cos_to_axis: np.ndarray
    valid: np.ndarray
    body_only: list[str]

    @classmethod
    def build(cls, camera: CameraModel, face_px: int, render_invalid: bool = True) -> CubeMapLookup:
        """Assign each pixel's ray to a face and a texel.

        render_invalid: also fill pixels outside the valid field of view that have
        an image (e.g. the car body in the centre of an omni image).
        """
        rays = camera.pixel_rays().astype(np.float64)  # (H, W, 3) unit rays
        valid = camera.valid_mask()
        has_ray = np.all(np.isfinite(rays), axis=-1)
        use = has_ray if render_invalid else valid
        focal = (face_px - 3.0) / 2.0  # tan = +-1 at 1.5 px inside the border
        c = (face_px - 1) / 2.0
        H, W = valid.shape
        map_x = np.full((H, W), -10.0, np.float32)
        map_y = np.full((H, W), -10.0, np.float32)
        cos_axis = np.zeros((H, W), np.float32)
        names = list(_FACE_DIRS)
        # the face of a ray is that of its largest-magnitude coordinate
        r = np.where(use[..., None], rays, 0.0)
        axis = np.argmax(np.abs(r), axis=-1)
        sign = np.take_along_axis(r, axis[..., None], axis=-1)[..., 0] >= 0
        face_index = np.where(use, axis * 2 + (~sign), -1)  # +x,-x,+y,-y,+z,-z
        used_faces = [names[i] for i in range(6) if np.any(face_index == i)]
        for slot, name in enumerate(used_faces):
            sel = face_index == names.index(name)
            d = rays[sel] @ face_rotation(name)  # ray in face (GL) coordinates
            depth_dir = -d[:, 2]
            map_x[sel] = c + focal * d[:, 0] / depth_dir
            map_y[sel] = slot * face_px + c - focal * d[:, 1] / depth_dir
            cos_axis[sel] = depth_dir
        m1, m2 = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
        # faces that only valid-less pixels (the car body under an omni mirror) look up
        body_only = [n for n in used_faces if not np.any(valid & (face_index == names.index(n)))]
        return cls(used_faces, face_px, focal, map_x, map_y, m1, m2, cos_axis, valid, body_only)


def finest_pixel_angle_rad(camera: CameraModel) -> float:
    """Angle between neighbouring pixel rays where the camera samples finest [rad] (1st
    percentile over its valid view; 0.01 when it has none)."""
    angle = pixel_angle_rad(camera)[camera.valid_mask()]
    return float(np.percentile(angle[angle > 0], 1)) if np.any(angle > 0) else 0.01


def prefilter_sigma_px(camera: CameraModel, focal_px: float) -> float:
    """Gaussian sigma [face px] that low-passes faces of focal length focal_px [px] to half
    the camera's finest pixel at the face centre; 0 when the faces are not finer."""
    finest_rad = finest_pixel_angle_rad(camera)
    texel_rad = float(np.arctan(1.0 / focal_px))  # at the face centre, its coarsest
    return 0.5 * finest_rad / texel_rad if finest_rad > texel_rad else 0.0


class OmniRenderer:
    """Renders camera images of a pyrender scene pair (colour, vehicle id).

    The colour scene is lit and shaded; the id scene holds meshes whose vertex
    colours encode vehicle ids (see `sim.scene`), rendered FLAT.
    """

    def __init__(
        self,
        camera: CameraModel,
        face_px: int = 512,
        z_near: float = 0.05,
        z_far: float = 400.0,
        cache_body_faces: bool = True,
    ) -> None:
        """cache_body_faces: render the faces that only show the car body (which moves
        with the camera) once and reuse them: at the first pose rendered, or at the pose
        given to `keep_body_faces` first (a drive gives its frame 0's, so that a render
        resumed at any frame writes the same body pixels as an uninterrupted one)."""
        self.camera = camera
        self.cache_body_faces = cache_body_faces
        self._face_cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.lookup = CubeMapLookup.build(camera, face_px)
        # anti-aliasing: a camera pixel is a bilinear point sample of a face; faces finer
        # than the camera are low-passed first, to about the camera's pixel (Gaussian,
        # sigma half a camera pixel at the face centre), so that texture finer than the
        # pixel averages out instead of aliasing (`remap_color`)
        self.prefilter_sigma_px = prefilter_sigma_px(camera, self.lookup.focal_px)
        fov = 2.0 * np.arctan((face_px / 2.0) / self.lookup.focal_px)
        self._gl_camera = pyrender.PerspectiveCamera(
            yfov=fov, aspectRatio=1.0, znear=z_near, zfar=z_far
        )
        self._renderer = pyrender.OffscreenRenderer(face_px, face_px)
        self._R_face = {n: face_rotation(n) for n in self.lookup.faces}

    def close(self) -> None:
        self._renderer.delete()

    def _face_poses(self, T_world_cam: np.ndarray) -> list[np.ndarray]:
        poses = []
        for name in self.lookup.faces:
            T = np.eye(4)
            T[:3, :3] = T_world_cam[:3, :3] @ self._R_face[name]
            T[:3, 3] = T_world_cam[:3, 3]
            poses.append(T)
        return poses

    def keep_body_faces(
        self, scene: pyrender.Scene, T_world_cam: np.ndarray, flat: bool = False
    ) -> None:
        """Render the faces that only show the car body at T_world_cam and keep them for
        every later `render_atlas` of ``scene`` (with the same ``flat``); faces already
        kept stay as they are, and nothing happens without ``cache_body_faces``."""
        if not self.cache_body_faces:
            return
        todo = [n for n in self.lookup.body_only if (id(scene), flat, n) not in self._face_cache]
        if not todo:
            return
        node = scene.add(self._gl_camera, pose=np.eye(4))
        flags = pyrender.RenderFlags.FLAT if flat else pyrender.RenderFlags.NONE
        try:
            for name, pose in zip(self.lookup.faces, self._face_poses(T_world_cam), strict=True):
                if name in todo:
                    scene.set_pose(node, pose)
                    self._face_cache[(id(scene), flat, name)] = self._renderer.render(
                        scene, flags=flags
                    )
        finally:
            scene.remove_node(node)

    def render_atlas(
        self,
        scene: pyrender.Scene,
        T_world_cam: np.ndarray,
        flat: bool = False,
        depth: bool = False,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Face atlas (n_faces * F, F, 3) uint8 and optionally depth (n_faces * F, F)."""
        node = scene.add(self._gl_camera, pose=np.eye(4))
        flags = pyrender.RenderFlags.FLAT if flat else pyrender.RenderFlags.NONE
        colors, depths = [], []
        try:
            for name, pose in zip(self.lookup.faces, self._face_poses(T_world_cam), strict=True):
                key = (id(scene), flat, name)
                if key in self._face_cache:
                    c, d = self._face_cache[key]
                else:
                    scene.set_pose(node, pose)
                    c, d = self._renderer.render(scene, flags=flags)
                    if self.cache_body_faces and name in self.lookup.body_only:
                        self._face_cache[key] = (c, d)
                colors.append(c)
                depths.append(d)
        finally:
            scene.remove_node(node)
        atlas = np.concatenate(colors, axis=0)
        return atlas, (np.concatenate(depths, axis=0) if depth else None)

    def remap_color(self, atlas: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 image by bilinear lookup into the colour atlas, which is first
        low-passed in place (``prefilter_sigma_px``)."""
        lk = self.lookup
        if self.prefilter_sigma_px > 0:  # face by face (no blur across a face border), in
            # place; faces that only show the car body (outside the valid view) are left
            F, sig = lk.face_px, self.prefilter_sigma_px
            for i, name in enumerate(lk.faces):
                if name not in lk.body_only:
                    face = atlas[i * F : (i + 1) * F]
                    cv2.GaussianBlur(face, (0, 0), sig, dst=face)
        return cv2.remap(atlas, lk.map1, lk.map2, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)

    def remap_nearest(self, atlas: np.ndarray) -> np.ndarray:
        lk = self.lookup
        return cv2.remap(
            atlas, lk.map_x, lk.map_y, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT
        )

    def range_image(self, depth_atlas: np.ndarray) -> np.ndarray:
        """(H, W) float32 range along each pixel's ray [m]; inf where nothing was hit."""
        z = self.remap_nearest(depth_atlas.astype(np.float32))
        with np.errstate(divide="ignore", invalid="ignore"):
            rng = np.where(z > 0, z / np.maximum(self.lookup.cos_to_axis, 1e-6), np.inf)
        return rng.astype(np.float32)
