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
from sim.gl import draw, linear_depth_m, pyrender
from sim.machine import note_gl_context

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
    face_px: side of a whole face [px]; focal_px: its focal length [px].
    window_px: (width, height) of the part of each face rendered [px] (the whole face,
        or the smallest window that holds every pixel asked for, when windowed).
    window_origin: per face, the (col, row) of its window's corner in the whole face [px].
    map_x, map_y, map1, map2: maps for ``cv2.remap`` into the face atlas (windows
        stacked vertically, each ``window_px[1]`` tall).
    cos_to_axis: (H, W) float32, -d_face_z of each pixel's unit ray: converts the
        rendered z-depth to range along the ray.
    valid: (H, W) bool, pixels with a valid ray; pixels: (H, W) bool, those looked up.
    body_only: faces that no valid pixel sees (the car body under an omni mirror).
    """

    faces: list[str]
    face_px: int
    focal_px: float
    window_px: tuple[int, int]
    window_origin: list[tuple[int, int]]
    map_x: np.ndarray
    map_y: np.ndarray
    map1: np.ndarray
    map2: np.ndarray
    cos_to_axis: np.ndarray
    valid: np.ndarray
    pixels: np.ndarray
    body_only: list[str]

    @classmethod
    def build(
        cls,
        camera: CameraModel,
        face_px: int,
        render_invalid: bool = True,
        pixels: np.ndarray | None = None,
        windowed: bool = False,
    ) -> CubeMapLookup:
        """Assign each pixel's ray to a face and a texel.

        render_invalid: also fill pixels outside the valid field of view that have
            an image (e.g. the car body in the centre of an omni image).
        pixels: (H, W) bool, only these pixels (default: by render_invalid).
        windowed: render only the window of each face that these pixels see.
        """
        rays = camera.pixel_rays().astype(np.float64)  # (H, W, 3) unit rays
        valid = camera.valid_mask()
        has_ray = np.all(np.isfinite(rays), axis=-1)
        use = (has_ray if render_invalid else valid) if pixels is None else pixels & has_ray
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
        coords = {}
        for name in used_faces:
            sel = face_index == names.index(name)
            d = rays[sel] @ face_rotation(name)  # ray in face (GL) coordinates
            depth_dir = -d[:, 2]
            coords[name] = (sel, c + focal * d[:, 0] / depth_dir, c - focal * d[:, 1] / depth_dir)
            cos_axis[sel] = depth_dir
        if windowed and used_faces:  # 2 texels of margin for the bilinear lookup
            lo = {
                n: (max(0, int(np.floor(x.min())) - 2), max(0, int(np.floor(y.min())) - 2))
                for n, (_, x, y) in coords.items()
            }
            hi = {
                n: (
                    min(face_px, int(np.ceil(x.max())) + 3),
                    min(face_px, int(np.ceil(y.max())) + 3),
                )
                for n, (_, x, y) in coords.items()
            }
            win = (
                max(hi[n][0] - lo[n][0] for n in used_faces),
                max(hi[n][1] - lo[n][1] for n in used_faces),
            )
            origin = [
                (min(lo[n][0], face_px - win[0]), min(lo[n][1], face_px - win[1]))
                for n in used_faces
            ]
        else:
            win, origin = (face_px, face_px), [(0, 0)] * len(used_faces)
        for slot, name in enumerate(used_faces):
            sel, x, y = coords[name]
            map_x[sel] = x - origin[slot][0]
            map_y[sel] = slot * win[1] + y - origin[slot][1]
        m1, m2 = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
        # faces that only valid-less pixels (the car body under an omni mirror) look up
        body_only = [n for n in used_faces if not np.any(valid & (face_index == names.index(n)))]
        return cls(
            used_faces,
            face_px,
            focal,
            win,
            origin,
            map_x,
            map_y,
            m1,
            m2,
            cos_axis,
            valid,
            use,
            body_only,
        )

    def face_masks(self) -> list[np.ndarray]:
        """(H, W) bool per face: the pixels that look it up."""
        h = self.window_px[1]
        slot = np.where(self.pixels, np.floor(self.map_y / h), -1)
        return [slot == i for i in range(len(self.faces))]

    def gl_cameras(self, z_near: float, z_far: float) -> list[pyrender.IntrinsicsCamera]:
        """One GL camera per face that renders its window: the face's centre (c, c) in
        centre-index coordinates of the whole face is (c - x0, c - y0) in its window's;
        pyrender puts a pixel's centre at +0.5 from its index, rows down from the top."""
        c = (self.face_px - 1) / 2.0
        return [
            pyrender.IntrinsicsCamera(
                fx=self.focal_px,
                fy=self.focal_px,
                cx=c - x0 + 0.5,
                cy=c - y0 + 0.5,
                znear=z_near,
                zfar=z_far,
            )
            for x0, y0 in self.window_origin
        ]


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
        pixels: np.ndarray | None = None,
        windowed: bool = False,
    ) -> None:
        """cache_body_faces: render the faces that only show the car body (which moves
        with the camera) once and reuse them: at the first pose rendered, or at the pose
        given to `keep_body_faces` first (a drive gives its frame 0's, so that a render
        resumed at any frame writes the same body pixels as an uninterrupted one).
        pixels, windowed: see `CubeMapLookup.build`."""
        self.camera = camera
        self.cache_body_faces = cache_body_faces
        self._face_cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        self.lookup = CubeMapLookup.build(camera, face_px, pixels=pixels, windowed=windowed)
        # anti-aliasing: a camera pixel is a bilinear point sample of a face; faces finer
        # than the camera are low-passed first, to about the camera's pixel (Gaussian,
        # sigma half a camera pixel at the face centre), so that texture finer than the
        # pixel averages out instead of aliasing (`remap_color`)
        self.prefilter_sigma_px = prefilter_sigma_px(camera, self.lookup.focal_px)
        self._gl_cameras = self.lookup.gl_cameras(z_near, z_far)
        self._renderer = pyrender.OffscreenRenderer(*self.lookup.window_px)
        note_gl_context()  # the renderer recorded with the drive (`sim.machine`)
        self._R_face = {n: face_rotation(n) for n in self.lookup.faces}
        self._depth_lookup: tuple | None = None  # `_nearest_elements`, for `range_image`

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
        node = scene.add(self._gl_cameras[0], pose=np.eye(4))
        flags = pyrender.RenderFlags.FLAT if flat else pyrender.RenderFlags.NONE
        try:
            for slot, (name, pose) in enumerate(
                zip(self.lookup.faces, self._face_poses(T_world_cam), strict=True)
            ):
                if name in todo:
                    node.camera = self._gl_cameras[slot]
                    scene.set_pose(node, pose)
                    c, d = draw(self._renderer, scene, flags)
                    self._face_cache[(id(scene), flat, name)] = (c.copy(), d.copy())
        finally:
            node.camera = self._gl_cameras[0]  # the one the scene registered
            scene.remove_node(node)

    def render_atlas(
        self,
        scene: pyrender.Scene,
        T_world_cam: np.ndarray,
        flat: bool = False,
        depth: bool = False,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Face atlas (n_faces * h, w, 3) uint8 and optionally the depth-buffer codes
        (n_faces * h, w) uint32 (`sim.gl.draw`; `range_image`), with (w, h) the faces'
        window (``lookup.window_px``)."""
        node = scene.add(self._gl_cameras[0], pose=np.eye(4))
        flags = pyrender.RenderFlags.FLAT if flat else pyrender.RenderFlags.NONE
        w, h = self.lookup.window_px
        n = len(self.lookup.faces)
        atlas = np.empty((n * h, w, 3), np.uint8)
        codes = np.empty((n * h, w), np.uint32) if depth else None
        try:
            for slot, (name, pose) in enumerate(
                zip(self.lookup.faces, self._face_poses(T_world_cam), strict=True)
            ):
                key = (id(scene), flat, name)
                if key in self._face_cache:
                    c, d = self._face_cache[key]
                else:
                    node.camera = self._gl_cameras[slot]
                    scene.set_pose(node, pose)
                    c, d = draw(self._renderer, scene, flags)
                    if self.cache_body_faces and name in self.lookup.body_only:
                        self._face_cache[key] = (c.copy(), d.copy())
                atlas[slot * h : (slot + 1) * h] = c
                if codes is not None:
                    codes[slot * h : (slot + 1) * h] = d
        finally:
            node.camera = self._gl_cameras[0]  # the one the scene registered
            scene.remove_node(node)
        return atlas, codes

    def remap_color(self, atlas: np.ndarray) -> np.ndarray:
        """(H, W, 3) uint8 image by bilinear lookup into the colour atlas, which is first
        low-passed in place (``prefilter_sigma_px``)."""
        lk = self.lookup
        if self.prefilter_sigma_px > 0:  # face by face (no blur across a face border), in
            # place; faces that only show the car body (outside the valid view) are left
            F, sig = lk.window_px[1], self.prefilter_sigma_px
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

    def range_image(self, depth_codes: np.ndarray) -> np.ndarray:
        """(H, W) float32 range along each pixel's ray [m]; inf where nothing was hit.
        depth_codes: `render_atlas`'s depth; only the pixels looked up are converted."""
        if self._depth_lookup is None:
            self._depth_lookup = self._nearest_elements(depth_codes.shape)
        pixel, element, cos = self._depth_lookup
        cam = self._gl_cameras[0]
        z = linear_depth_m(depth_codes.reshape(-1)[element], cam.znear, cam.zfar)
        out = np.full(self.lookup.map_x.shape, np.inf, np.float32)
        out.reshape(-1)[pixel] = z / cos
        return out

    def _nearest_elements(self, atlas_shape: tuple) -> tuple[np.ndarray, ...]:
        """The pixels that `remap_nearest` fills from an atlas (h, w), as flat indices
        (N,), the atlas elements they read (N,) and their ``cos_to_axis`` (N,) (>= 1e-6)."""
        n = int(np.prod(atlas_shape))
        if n >= 1 << 24:
            raise ValueError(f"atlas of {n} elements too large for a float32 index")
        index = cv2.remap(
            np.arange(n, dtype=np.float32).reshape(atlas_shape),
            self.lookup.map_x,
            self.lookup.map_y,
            cv2.INTER_NEAREST,
            borderMode=cv2.BORDER_CONSTANT,
            borderValue=-1.0,
        ).reshape(-1)
        pixel = np.flatnonzero(index >= 0)
        cos = np.maximum(self.lookup.cos_to_axis.reshape(-1)[pixel], np.float32(1e-6))
        return pixel, index[pixel].astype(np.int64), cos
