"""Render a scenario into a drive folder: frames, ids, range, ground truth, video.

Layout of ``out/``::

    frames/NNNNNN.png   omni (or pinhole) RGB frames after sensor effects
    ids/NNNNNN.png      uint16 vehicle id + 1 per pixel (0 = no vehicle)
    range/NNNNNN.png    uint16 range along the ray [cm] (0 = sky / nothing)
    gt/NNNNNN.json      per-frame ground truth, written last: marks the frame done
    groundtruth.jsonl   all frames, assembled when every frame is done
    can.csv             CAN messages (t_s, speed_mps)
    timestamps.csv      frame times (frame, t_s)
    camera.yaml         the camera and its mount
    body_mask.png       uint8, 255 where the camera sees the ego car's own body (omni
                        cameras; `estimator.camera.files.load_body_mask`)
    scenario.yaml       the resolved scenario
    render.json         how the frames are rendered ({"renderer": ..., "face_px": ...});
                        a resume must match
    drive.mp4           the frames as a video
    manifest.json       written last: {"complete": true, ...}; "machine": what rendered
                        the frames (CPU, versions, OpenGL renderer: `sim.machine`)

Every file is written atomically. An interrupted render resumes: the world is
re-simulated (deterministic under the seed) and finished frames are skipped.
"""

from __future__ import annotations

import json
import time
from collections.abc import Iterable, Iterator, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path

import cv2
import numpy as np

from estimator import fileio as io
from estimator.camera.files import BODY_MASK_FILE, resolve_camera, save_camera
from estimator.camera.models import CameraModel
from estimator.camera.mount import CameraMount
from estimator.frame_times import StageClock
from estimator.progress import track
from sim.camera_motion import (
    CameraPose,
    T_world_car,
    Vibration,
    camera_pose,
    motion_between,
)
from sim.can import can_at, can_messages
from sim.frame_renderer import (
    RENDERERS,
    CubeFrameRenderer,
    FrameImages,
    PlaneFrameRenderer,
    default_face_px,
    imaged_mask,
    object_face_px,
)
from sim.highway import EGO_REAR_AXLE_X_M, WorldFrame, simulate
from sim.machine import machine_info
from sim.scenario import Scenario
from sim.scene import (
    build_static_scene,
    vehicle_corners_world,
)
from sim.sensor import SensorModel, apply_sensor, exposure_times, gain_sequence


class DriveError(RuntimeError):
    """A drive folder that cannot be (re)used."""


def frame_name(k: int) -> str:
    return f"{k:06d}"


@dataclass
class DriveResult:
    out_dir: Path
    n_frames: int
    rendered: int
    render_ms_per_frame: float


def static_scene_for(
    frames: list[WorldFrame], scenario: Scenario, bridge_road, seed: int
) -> tuple[list, tuple[float, float, float, float]]:
    """The static scene's meshes (`sim.scene.build_static_scene`) within view_range_m of
    the drive, and that area (xmin, xmax, ymin, ymax) [m]."""
    xs = np.array([f.ego.x_m for f in frames])
    ys = np.array([f.ego.y_m for f in frames])
    r = scenario.view_range_m
    area = (xs.min() - r, xs.max() + r, ys.min() - r, ys.max() + r)
    rng = np.random.default_rng([seed, 1])
    return build_static_scene(bridge_road, area, rng), area


def _vehicle_record(v, T_world_cam_nominal: np.ndarray, visible_px: int) -> dict:
    box_w = vehicle_corners_world(v)
    T_cw = np.linalg.inv(T_world_cam_nominal)
    box_c = box_w @ T_cw[:3, :3].T + T_cw[:3, 3]
    return {
        "id": v.id,
        "x_m": v.x_m,
        "y_m": v.y_m,
        "yaw_rad": v.yaw_rad,
        "speed_mps": v.speed_mps,
        "yaw_rate_rps": v.yaw_rate_rps,
        "length_m": v.length_m,
        "width_m": v.width_m,
        "height_m": v.height_m,
        "box_world_m": box_w.round(4),
        "box_cam_m": box_c.round(4),
        "visible_px": int(visible_px),
    }


def scene_flow_px(
    camera: CameraModel,
    rays: np.ndarray,
    range_m: np.ndarray,
    ids: np.ndarray,
    a: CameraPose,
    b: CameraPose,
    displacement_m: dict[int, np.ndarray],
    step: int = 4,
) -> np.ndarray:
    """(H, W, 2) image motion between poses a and b [px], for motion blur.

    Computed on every ``step``-th pixel and interpolated (the flow is smooth).
    rays: (H, W, 3) unit rays of the actual camera; range_m: (H, W), inf for sky;
    ids: (H, W) vehicle ids (-1 none, 0 the ego car, which moves with the camera);
    displacement_m: world displacement (3,) of each vehicle id between a and b
    (translation only: the vehicles' own rotation is neglected).
    """
    return scene_flows_px(camera, rays, range_m, ids, a, [(b, displacement_m)], step)[0]


def scene_flows_px(
    camera: CameraModel,
    rays: np.ndarray,
    range_m: np.ndarray,
    ids: np.ndarray,
    a: CameraPose,
    moves: Sequence[tuple[CameraPose, dict[int, np.ndarray]]],
    step: int = 4,
) -> list[np.ndarray]:
    """`scene_flow_px` from pose a to each (b, displacement_m) of moves, sharing the
    scene points seen at a."""
    H, W = range_m.shape
    d = rays[::step, ::step].reshape(-1, 3).astype(np.float64)
    r = range_m[::step, ::step].reshape(-1).astype(np.float64)
    i = ids[::step, ::step].reshape(-1)
    h, w = range_m[::step, ::step].shape
    vv, uu = np.mgrid[0:H:step, 0:W:step]
    w_a = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(np.float64)
    R_wa, p_a = a.T_world_actual[:3, :3], a.T_world_actual[:3, 3]
    dirs_w = d @ R_wa.T
    finite = np.isfinite(r) & np.all(np.isfinite(d), axis=1)
    X = p_a + r[finite, None] * dirs_w[finite]
    i_finite = i[finite]
    ego = i == 0  # the ego car's body moves with the camera
    flows = []
    for b, displacement_m in moves:
        R_wb, p_b = b.T_world_actual[:3, :3], b.T_world_actual[:3, 3]
        P_b = dirs_w @ R_wb  # points at infinity: rotation only
        moved = X.copy()
        if displacement_m:  # each vehicle's points by its displacement
            vids = np.array(sorted(displacement_m), dtype=i.dtype)
            table = np.array([displacement_m[v] for v in vids.tolist()], np.float64)
            at = np.minimum(np.searchsorted(vids, i_finite), len(vids) - 1)
            own = vids[at] == i_finite
            moved[own] += table[at[own]]
        P_b[finite] = (moved - p_b) @ R_wb
        flow = camera.project(P_b) - w_a
        flow[ego] = 0.0
        flow = np.nan_to_num(flow, nan=0.0, posinf=0.0, neginf=0.0).reshape(h, w, 2)
        flows.append(cv2.resize(flow.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR))
    return flows


def vehicle_displacements(f_a: WorldFrame, f_b: WorldFrame) -> dict[int, np.ndarray]:
    """World displacement (3,) of every vehicle present in both frames [m]."""
    pos_b = {v.id: (v.x_m, v.y_m) for v in (f_b.ego, *f_b.others)}
    return {
        v.id: np.array([pos_b[v.id][0] - v.x_m, pos_b[v.id][1] - v.y_m, 0.0])
        for v in (f_a.ego, *f_a.others)
        if v.id in pos_b
    }


class DriveRenderer:
    """Everything needed to produce the frames of one simulated drive.

    Holds the world frames, camera poses, CAN messages and the frame renderer
    (`sim.frame_renderer`: ``renderer="plane"``, the default, or ``"cube"``);
    `produce(k)` renders frame k with sensor effects.
    """

    def __init__(
        self,
        scenario: Scenario,
        camera: CameraModel,
        mount: CameraMount,
        frames: list[WorldFrame],
        road,
        face_px: int | None = None,
        renderer: str = "plane",
    ) -> None:
        if renderer not in RENDERERS:
            raise ValueError(f"renderer must be one of {RENDERERS}, got {renderer!r}")
        # the sensor's vignetting is the camera's photometric calibration: the camera file
        # of the drive records it, as a real camera's flat-field calibration would
        camera = camera.replace(vignetting=scenario.sensor.vignetting)
        self.scenario, self.camera, self.mount, self.frames = scenario, camera, mount, frames
        n = len(frames)
        rng_world = np.random.default_rng([scenario.seed, 0])
        self.vibration = vib = Vibration.seeded(
            scenario.vibration.amplitude_deg, scenario.vibration.frequency_hz, rng_world
        )
        self.poses = [
            camera_pose(T_world_car(f.ego.x_m, f.ego.y_m, f.ego.yaw_rad), mount, vib, f.t_s)
            for f in frames
        ]
        t = np.array([f.t_s for f in frames])
        speed = np.array([f.ego.speed_mps for f in frames])
        c = scenario.can
        self.t_msg, self.v_msg = can_messages(
            t,
            speed,
            c.rate_hz,
            c.speed_bias,
            c.speed_noise_mps,
            c.quantization_mps,
            np.random.default_rng([scenario.seed, 2]),
        )
        self.can_frame = can_at(t, self.t_msg, self.v_msg)
        self.sensor = SensorModel(**scenario.sensor.model_dump())
        self.gains = gain_sequence(
            n, self.sensor.gain_drift, np.random.default_rng([scenario.seed, 3])
        )
        self.vignette = camera.vignetting_gain().astype(np.float32)  # (H, W)
        self.road = road
        self.renderer = renderer
        if face_px is None:
            plane = renderer == "plane"
            face_px = object_face_px(camera) if plane else default_face_px(camera)
        self.face_px = face_px
        self._renderer: PlaneFrameRenderer | CubeFrameRenderer | None = None

    def settings(self) -> dict:
        """How the frames are rendered (``render.json``)."""
        return {"renderer": self.renderer, "face_px": self.face_px}

    def _open(self) -> PlaneFrameRenderer | CubeFrameRenderer:
        if self._renderer is None:
            static, area = static_scene_for(
                self.frames, self.scenario, self.road, self.scenario.seed
            )
            if self.renderer == "plane":
                T_ref = self.poses[0].T_world_nominal
                r = PlaneFrameRenderer(
                    self.camera, T_ref, self.face_px, True, static, area, self.scenario.shadows
                )
            else:
                r = CubeFrameRenderer(self.camera, static, self.face_px)
            self._rays = self.camera.pixel_rays()
            self._mask = imaged_mask(self.camera)
            # the car body is drawn once, always at frame 0, whatever frame this render
            # starts at, so that a resumed render is byte-identical to an uninterrupted one
            f0 = self.frames[0]
            r.start((f0.ego, *f0.others), self.poses[0].T_world_actual)
            self._renderer = r
        return self._renderer

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
            self._renderer = None

    def _moved(self, k: int, tau_s: float) -> tuple[CameraPose, dict[int, np.ndarray]]:
        """The camera's pose and the vehicles' displacements [m] at tau_s from frame k's time,
        for the motion blur: the simulator moves every vehicle straight and turns it evenly
        between frames (linear in x, y and yaw toward the next frame for tau_s > 0, from
        the previous one before; the first and the last frame extrapolate the one they
        have); the camera's vibration at that very time."""
        n = len(self.frames)
        j = k + 1 if (tau_s > 0 and k + 1 < n) or k == 0 else k - 1
        a, b = self.frames[k], self.frames[j]
        f = tau_s / (b.t_s - a.t_s)  # fraction of the way to frame j (< 0: away from it)
        dyaw = (b.ego.yaw_rad - a.ego.yaw_rad + np.pi) % (2 * np.pi) - np.pi
        car = T_world_car(
            a.ego.x_m + f * (b.ego.x_m - a.ego.x_m),
            a.ego.y_m + f * (b.ego.y_m - a.ego.y_m),
            a.ego.yaw_rad + f * dyaw,
        )
        pose = camera_pose(car, self.mount, self.vibration, a.t_s + tau_s)
        moved = {i: f * d for i, d in vehicle_displacements(a, b).items()}
        return pose, moved

    def produce(self, k: int) -> FrameImages:
        """Frame k with sensor effects; ``stage_seconds`` says where its time went."""
        return self._finish(k, *self._render(k))

    def produce_many(self, ks: Iterable[int]) -> Iterator[tuple[int, FrameImages]]:
        """(k, frame k) for each k in order, as `produce` makes them; the motion blur and
        sensor effects of one frame run in a worker thread beside the rendering of the
        next (the same images: each frame's randomness is seeded by its index)."""
        with ThreadPoolExecutor(max_workers=1) as pool:
            pending = None
            for k in ks:
                try:
                    rendered = self._render(k)
                except BaseException:  # interrupted: the frame made before is not lost
                    if pending is not None:
                        yield pending[0], pending[1].result()
                    raise
                job = pool.submit(self._finish, k, *rendered)
                if pending is not None:
                    yield pending[0], pending[1].result()
                pending = (k, job)
            if pending is not None:
                yield pending[0], pending[1].result()

    def _render(self, k: int) -> tuple[FrameImages, dict[str, float]]:
        """Frame k before sensor effects, and the seconds of its rendering stages."""
        renderer = self._open()
        renderer.clock.start()
        frame = self.frames[k]
        seen = renderer.render((frame.ego, *frame.others), self.poses[k].T_world_actual)
        return seen, dict(renderer.clock.seconds)

    def _finish(self, k: int, seen: FrameImages, stages: dict[str, float]) -> FrameImages:
        """Frame k with motion blur and sensor effects on its rendered images."""
        pose = self.poses[k]
        clock = StageClock()
        image, ids, range_m = seen.image, seen.ids, seen.range_m
        blur = None
        if self.sensor.motion_blur and len(self.frames) > 1:
            # the image motion at the first and the last sample time of the exposure; at the
            # others it is scaled by time from the nearer one (each side of the frame's time
            # moves towards its own neighbour frame): exact to first order, the second-order
            # term over +-4 ms is below 0.001 px for a 160 px/s^2 change of the motion
            taus = exposure_times(self.sensor.exposure_s)
            ends = dict(
                zip(
                    (taus.min(), taus.max()),
                    scene_flows_px(
                        self.camera,
                        self._rays,
                        range_m,
                        ids,
                        pose,
                        [self._moved(k, tau) for tau in (taus.min(), taus.max())],
                    ),
                    strict=True,
                )
            )
            blur = [
                np.float32(tau / (taus.max() if tau > 0 else taus.min()))
                * ends[taus.max() if tau > 0 else taus.min()]
                for tau in taus
            ]
        clock.lap("motion")
        rng = np.random.default_rng([self.scenario.seed, 4, k])
        out = apply_sensor(
            image,
            self.sensor,
            rng,
            gain=float(self.gains[k]),
            vignette=self.vignette,
            blur_px=blur,
            mask=self._mask,
        )
        clock.lap("sensor")
        self.stage_seconds = {**stages, **clock.seconds}
        return FrameImages(out, ids, range_m)

    def groundtruth(self, k: int, ids: np.ndarray) -> dict:
        return frame_groundtruth(k, self.frames, self.poses, ids, self.can_frame)


def check_renderer(scenario: Scenario, renderer: str) -> None:
    """A renderer that exists and can draw the scenario (ValueError naming both)."""
    if renderer not in RENDERERS:
        raise ValueError(f"renderer must be one of {RENDERERS}, got {renderer!r}")
    if scenario.shadows and renderer != "plane":
        raise ValueError(
            f"scenario {scenario.name!r}: key 'shadows': the {renderer!r} renderer draws no "
            "shadows; use the plane renderer"
        )


def prepare_drive(
    scenario: Scenario,
    face_px: int | None = None,
    renderer: str = "plane",
) -> DriveRenderer:
    """Simulate the scenario's whole drive and set up its renderer.

    The whole drive, also where only its first frames are rendered: the scenery is laid
    out along the whole path, so that the first N frames of a drive are the same whatever
    N is rendered.
    """
    check_renderer(scenario, renderer)
    camera, mount = resolve_camera(scenario.camera)
    if mount.rear_axle_x_m is None:  # the ego car's geometry goes with the recording
        mount = replace(mount, rear_axle_x_m=EGO_REAR_AXLE_X_M)
    n = scenario.n_frames
    frames, road = simulate(
        scenario.env,
        scenario.env_config,
        scenario.seed,
        scenario.fps,
        n / scenario.fps,
        scenario.ego_policy,
        scenario.ego_speed_mps,
        return_road=True,
        traffic=scenario.traffic,
    )
    frames = frames[:n]
    if len(frames) < n:
        raise DriveError(f"simulation produced {len(frames)} frames, expected {n}")
    return DriveRenderer(scenario, camera, mount, frames, road, face_px, renderer)


def render_drive(
    scenario: Scenario,
    out_dir: Path,
    *,
    progress: bool = True,
    face_px: int | None = None,
    max_frames: int | None = None,
    renderer: str = "plane",
) -> DriveResult:
    """Simulate and render ``scenario`` into ``out_dir`` (resuming if possible)."""
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    resolved = scenario.to_dict()
    sc_path = out_dir / "scenario.yaml"
    if sc_path.exists():
        import yaml

        previous = yaml.safe_load(sc_path.read_text())
        if previous != resolved:
            raise DriveError(
                f"{out_dir} holds a render of a different scenario ({previous.get('name')!r}); "
                "use another --out folder or delete it"
            )
    n = scenario.n_frames if max_frames is None else min(scenario.n_frames, max_frames)
    manifest = _read_manifest(out_dir)
    if manifest.get("complete") and manifest.get("frames") == n:  # nothing to simulate either
        _write_body_mask(out_dir)  # renders made before drives held one
        return DriveResult(out_dir, n, 0, manifest.get("render_ms_per_frame") or float("nan"))
    drive = prepare_drive(scenario, face_px, renderer)
    io.write_yaml(sc_path, resolved)
    save_camera(out_dir / "camera.yaml", drive.camera, drive.mount)
    shown = drive.frames[:n]
    sent = drive.t_msg <= shown[-1].t_s + 1e-9  # the CAN messages up to the last frame
    io.write_text(
        out_dir / "can.csv",
        "t_s,speed_mps\n"
        + "".join(
            f"{a:.4f},{b:.4f}\n" for a, b in zip(drive.t_msg[sent], drive.v_msg[sent], strict=True)
        ),
    )
    io.write_text(
        out_dir / "timestamps.csv",
        "frame,t_s\n" + "".join(f"{k},{f.t_s:.6f}\n" for k, f in enumerate(shown)),
    )
    todo = [k for k in range(n) if not (out_dir / "gt" / f"{frame_name(k)}.json").exists()]
    _check_render_settings(out_dir, drive.settings(), resuming=len(todo) < n)
    render_times: list[float] = []
    try:
        t0 = time.perf_counter()
        frames = drive.produce_many(todo)
        for k, fr in track(frames, len(todo), f"render {scenario.name}", progress):
            name = frame_name(k)
            io.write_png(out_dir / "frames" / f"{name}.png", fr.image)
            io.write_png(out_dir / "ids" / f"{name}.png", (fr.ids + 1).astype(np.uint16))
            rng_cm = np.where(np.isfinite(fr.range_m), np.clip(fr.range_m * 100, 1, 65535), 0)
            io.write_png(out_dir / "range" / f"{name}.png", rng_cm.astype(np.uint16))
            if k == 0:
                _write_body_mask(out_dir)
            # written last: its presence marks the frame as done
            io.write_json(out_dir / "gt" / f"{name}.json", drive.groundtruth(k, fr.ids))
            render_times.append(time.perf_counter() - t0)  # between frames written
            t0 = time.perf_counter()
    finally:
        drive.close()
    ms = 1000 * float(np.median(render_times)) if render_times else float("nan")
    _finalise(out_dir, n, scenario, ms, machine_info() if todo else None)
    return DriveResult(out_dir, n, len(todo), ms)


def _write_body_mask(out_dir: Path) -> None:
    """``body_mask.png`` from frame 0's ids (the ego car's id 0 is written as 1; the body
    is drawn once and is the same in every frame), where the camera sees the body."""
    ids_path = out_dir / "ids" / f"{frame_name(0)}.png"
    if (out_dir / BODY_MASK_FILE).exists() or not ids_path.exists():
        return
    body = io.read_png(ids_path) == 1
    if body.any():
        io.write_png(out_dir / BODY_MASK_FILE, body.astype(np.uint8) * 255)


def _check_render_settings(out_dir: Path, settings: dict, resuming: bool) -> None:
    """Record how the frames are rendered (``render.json``); a resumed render must match.

    Frames of one drive must come from one renderer set-up: a resume with another face
    size (``--face-px``, or a new default) would mix two image qualities in one drive.
    """
    path = out_dir / "render.json"
    if resuming:
        before = json.loads(path.read_text()) if path.exists() else None
        if before is not None:  # written before there was a choice: the cube renderer
            before.setdefault("renderer", "cube")
        if before != settings:
            raise DriveError(
                f"{out_dir} holds frames rendered with {before or 'unrecorded settings'}, "
                f"this render uses {settings}; pass the same --renderer and --face-px, or "
                "use another "
                "--out folder"
            )
    io.write_json(path, settings)


def _read_manifest(out_dir: Path) -> dict:
    p = out_dir / "manifest.json"
    try:
        return json.loads(p.read_text()) if p.exists() else {}
    except json.JSONDecodeError:
        return {}


def frame_groundtruth(
    k: int,
    frames: list[WorldFrame],
    poses: list[CameraPose],
    ids: np.ndarray,
    can_frame: np.ndarray,
) -> dict:
    """The ground-truth record of frame k (see module docstring of sim.drive)."""
    f, pose = frames[k], poses[k]
    counts = np.bincount(ids[ids >= 0].ravel(), minlength=1) if np.any(ids >= 0) else np.zeros(1)
    rec = {
        "frame": k,
        "t_s": f.t_s,
        "ego": {
            "x_m": f.ego.x_m,
            "y_m": f.ego.y_m,
            "yaw_rad": f.ego.yaw_rad,
            "speed_mps": f.ego.speed_mps,
            "yaw_rate_rps": f.ego.yaw_rate_rps,
        },
        "T_world_cam_nominal": pose.T_world_nominal.round(6),
        "T_world_cam_actual": pose.T_world_actual.round(6),
        "A_rad": pose.A_cam_rad,
        "can_speed_mps": float(can_frame[k]),
        "motion_from_prev": None,
        "vehicles": [
            _vehicle_record(v, pose.T_world_nominal, counts[v.id] if v.id < len(counts) else 0)
            for v in f.others
        ],
    }
    if k > 0:
        m = motion_between(poses[k - 1], pose, f.t_s - frames[k - 1].t_s)
        rec["motion_from_prev"] = {
            "V_mps": m.V_mps,
            "W_rps": m.W_rps,
            "A_rad": m.A_rad,
            "H": m.H,
            "dt_s": m.dt_s,
        }
    return rec


def _finalise(
    out_dir: Path, n: int, scenario: Scenario, render_ms: float, machine: dict | None
) -> None:
    """groundtruth.jsonl, drive.mp4 and, last, manifest.json; render_ms: [ms] median a
    frame; machine: what rendered the frames (`sim.machine.machine_info`; None: nothing
    rendered now, the earlier manifest's is kept)."""
    lines = [(out_dir / "gt" / f"{frame_name(k)}.json").read_text() for k in range(n)]
    io.write_text(
        out_dir / "groundtruth.jsonl", "".join(json.dumps(json.loads(s)) + "\n" for s in lines)
    )
    write_video(
        out_dir / "drive.mp4",
        [out_dir / "frames" / f"{frame_name(k)}.png" for k in range(n)],
        scenario.fps,
    )
    before = _read_manifest(out_dir)
    if not np.isfinite(render_ms):
        render_ms = before.get("render_ms_per_frame")
    if machine is None:
        machine = before.get("machine")
    # written last: a folder without a complete manifest is not a finished drive
    io.write_json(
        out_dir / "manifest.json",
        {
            "complete": True,
            "frames": n,
            "scenario": scenario.name,
            "render_ms_per_frame": render_ms,
            "machine": machine,
        },
    )


def write_video(path: Path, frame_paths: list[Path], fps: float) -> None:
    import imageio.v2 as imageio

    def _w(p: Path) -> None:
        with imageio.get_writer(
            p, fps=fps, codec="libx264", quality=7, macro_block_size=16, format="FFMPEG"
        ) as w:
            for fp in frame_paths:
                w.append_data(io.read_png(fp))

    io.atomic_write(path, _w, suffix=".mp4")


def load_groundtruth(drive_dir: Path) -> list[dict]:
    """Read groundtruth.jsonl of a complete drive folder."""
    drive_dir = Path(drive_dir)
    manifest = drive_dir / "manifest.json"
    if not manifest.exists() or not json.loads(manifest.read_text()).get("complete"):
        raise DriveError(f"{drive_dir} is not a complete drive (no complete manifest.json)")
    with open(drive_dir / "groundtruth.jsonl") as fh:
        return [json.loads(line) for line in fh]
