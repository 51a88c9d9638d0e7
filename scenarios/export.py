"""A rendered drive's ground truth in formats other tools read (`omnibench export`).

- ``tum``: the true trajectory, ``groundtruth.tum`` (``t x y z qx qy qz qw``, the first
  frame's car frame; `scenarios.tum`), for evo.
- ``depth``: ``depth/NNNNNN.png``, uint16, the range along each pixel's ray in
  centimetres (0: no surface, the sky), with ``depth/scale.json``.
- ``coco``: ``coco.json``, COCO instances: one image per frame, one annotation per
  vehicle seen in it (not the ego car), its instance mask (RLE, pycocotools) and box
  ``[x, y, w, h]`` the extent of its id pixels; ``track_id`` the vehicle's id.
- ``flow``: ``flow/NNNNNN.npy``, (H, W, 2) float64, where each pixel of frame k is in
  frame k + 1 less where it is [px] (u, v), from the exact geometry: the pixel's surface
  point (the road plane's for road pixels, exactly; the range image's elsewhere) moved
  with what it belongs to (the world, a vehicle's rigid motion, or the ego car: then 0)
  and projected with the camera model at frame k + 1's pose. NaN where the point has no
  surface (sky), its vehicle has left, or it leaves the field of view.
- ``mot``: MOTChallenge ground truth of the bench's tracking evaluation set, the layout
  TrackEval's ``MotChallenge2DBox`` reads (``mot/<seq>/gt/gt.txt``, ``seqinfo.ini``,
  ``mot/seqmaps/omnibench-all.txt``; boxes the plan-view extents of the footprints in the
  ego road frame [m], `scenarios.mot`); with a track file, its tracks too
  (``trackers/tracker/data/<seq>.txt``).
- ``kitti-tracking``: ``kitti/label_02/<seq>.txt`` in KITTI's tracking label format and
  ``kitti/evaluate_tracking.seqmap.training`` (TrackEval's ``Kitti2DBox`` layout): one
  row per vehicle seen per frame (the vehicles of ``coco``), frame = the drive's frame
  (0-based), type ``Car``, truncated 0, occluded 0; the 2-D box the extent of its id
  pixels by pixel edges (left, top: its first column and row; right, bottom: its last
  plus 1, so right - left and bottom - top are COCO's w and h) [px]; the 3-D box in a
  KITTI camera frame at the ego road frame's origin (on the road under the camera's
  viewpoint): x right (-y of the ego road frame), y down, z forward (x), so location
  ``(x, y, z) = (-y_c, 0, x_c)`` of the footprint centre (x_c, y_c) [m] (on the road:
  y 0), dimensions ``h w l`` the vehicle's height, width, length [m], ``rotation_y =
  -(yaw + pi/2)`` of its heading yaw in the ego road frame, ``alpha = rotation_y -
  atan2(x, z)``, both wrapped to [-pi, pi) [rad].
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import numpy as np

FORMATS = ("tum", "depth", "coco", "flow", "mot", "kitti-tracking")
RANGE_UNIT_M = 0.01  # [m] per unit of the range images (sim/drive.py)
ROAD_Z_M = 0.05  # [m] a static surface within this of the road plane is the road


class ExportError(ValueError):
    """A format or a drive that cannot be exported; names it."""


def export_drive(
    drive_dir: Path,
    fmt: str,
    out_dir: Path,
    progress: bool = True,
    tracks: Path | None = None,
) -> list[Path]:
    """Write the drive's ground truth in ``fmt`` (`FORMATS`) under out_dir; the files.

    tracks: a track file (``tracks.csv`` or any file `omnibench evaluate` reads), for
    ``mot`` only: written beside the ground truth as TrackEval's tracker files."""
    from estimator.camera.files import load_camera
    from scenarios.evaluate import InputError, read_tracks_input
    from sim.drive import DriveError, load_groundtruth

    if fmt not in FORMATS:
        raise ExportError(f"unknown format {fmt!r}; choose one of {', '.join(FORMATS)}")
    if tracks is not None and fmt != "mot":
        raise ExportError(f"a track file is exported with --format mot, not {fmt!r}")
    drive_dir, out_dir = Path(drive_dir), Path(out_dir)
    try:
        gt = load_groundtruth(drive_dir)
    except (DriveError, OSError, ValueError) as e:
        raise ExportError(f"{drive_dir}: not a complete rendered drive: {e}") from None
    try:
        trk = read_tracks_input(tracks, len(gt)) if tracks is not None else None
    except InputError as e:
        raise ExportError(str(e)) from None
    if fmt == "mot":
        return _export_mot(drive_dir, out_dir, gt, trk, tracks)
    camera, _ = load_camera(drive_dir / "camera.yaml")
    out_dir.mkdir(parents=True, exist_ok=True)
    if fmt == "tum":
        from scenarios.tum import write_groundtruth_tum

        write_groundtruth_tum(gt, out_dir / "groundtruth.tum")
        return [out_dir / "groundtruth.tum"]
    if fmt == "depth":
        return _export_depth(drive_dir, out_dir, len(gt), progress)
    if fmt == "coco":
        return [_export_coco(drive_dir, out_dir, gt, camera, progress)]
    if fmt == "kitti-tracking":
        return _export_kitti(drive_dir, out_dir, gt, progress)
    return _export_flow(drive_dir, out_dir, gt, camera, progress)


def _frames(n: int, what: str, progress: bool):
    from estimator.progress import track

    return track(range(n), n, what, progress)


def _export_mot(
    drive_dir: Path, out_dir: Path, gt: list[dict], trk: dict | None, tracks: Path | None
) -> list[Path]:
    from scenarios import mot
    from scenarios.config import load_scenario
    from scenarios.evaluate import track_frames

    scenario = load_scenario(drive_dir / "scenario.yaml")
    seq = mot.sequence_name(scenario.name)
    frames = track_frames(trk or {}, gt, scenario.detection_range_m)
    if trk is not None and not mot.track_rows(frames):
        raise ExportError(
            f"{tracks}: no track with a box (box_x_m, box_y_m, box_yaw_rad, box_length_m, "
            "box_width_m) in frames 1 .. N-1: a MOT row is a box"
        )
    files = mot.write_gt(frames, out_dir / "mot", seq, scenario.fps)
    if trk is not None:
        path = out_dir / "trackers" / mot.TRACKER / "data" / f"{seq}.txt"
        path.parent.mkdir(parents=True, exist_ok=True)
        files.append(mot.write_tracks(frames, path))
    return files


def _export_depth(drive_dir: Path, out_dir: Path, n: int, progress: bool) -> list[Path]:
    from estimator.fileio import read_png, write_json, write_png

    (out_dir / "depth").mkdir(exist_ok=True)
    out = []
    for k in _frames(n, "export depth", progress):
        p = out_dir / "depth" / f"{k:06d}.png"
        write_png(p, read_png(drive_dir / "range" / f"{k:06d}.png").astype(np.uint16))
        out.append(p)
    write_json(
        out_dir / "depth" / "scale.json",
        {"quantity": "range along the pixel's ray", "unit_m": RANGE_UNIT_M, "no_surface": 0},
    )
    return out + [out_dir / "depth" / "scale.json"]


def _id_boxes(ids: np.ndarray) -> list[tuple[int, np.ndarray, list[int]]]:
    """(vehicle id, mask (H, W) bool, box [x, y, w, h] [px]: the extent of its pixels by
    pixel edges) of every vehicle in an id image (H, W) (-1: none, 0: the ego car)."""
    out = []
    for vid in np.unique(ids[ids > 0]):
        m = ids == vid
        rows, cols = np.nonzero(m)
        x0, y0 = int(cols.min()), int(rows.min())
        out.append((int(vid), m, [x0, y0, int(cols.max()) - x0 + 1, int(rows.max()) - y0 + 1]))
    return out


def _wrap(a: float) -> float:
    """An angle [rad] wrapped to [-pi, pi)."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def kitti_row(frame: int, gt_frame: dict, vehicle: dict, bbox: Sequence[int]) -> str:
    """A KITTI tracking label line of a GT record's vehicle (module docstring) with its
    2-D box [x, y, w, h] [px]."""
    from scenarios.runner import vehicle_footprint

    c = vehicle_footprint(gt_frame, vehicle).mean(axis=0)
    yaw = vehicle["yaw_rad"] - gt_frame["ego"]["yaw_rad"]  # heading in the ego road frame
    x, y, z = -float(c[1]), 0.0, float(c[0])
    ry = _wrap(-(yaw + math.pi / 2))
    alpha = _wrap(ry - math.atan2(x, z))
    x0, y0, w, h = bbox
    dims = (vehicle["height_m"], vehicle["width_m"], vehicle["length_m"])
    return " ".join(
        [f"{frame} {vehicle['id']} Car 0 0 {alpha:.6f}"]
        + [f"{v:.2f}" for v in (x0, y0, x0 + w, y0 + h)]
        + [f"{v:.6f}" for v in (*dims, x, y, z, ry)]
    )


def _export_kitti(drive_dir: Path, out_dir: Path, gt: list[dict], progress: bool) -> list[Path]:
    from estimator.fileio import read_png, write_text
    from scenarios import mot
    from scenarios.config import load_scenario

    seq = mot.sequence_name(load_scenario(drive_dir / "scenario.yaml").name)
    lines = []
    for k in _frames(len(gt), "export kitti-tracking", progress):
        ids = read_png(drive_dir / "ids" / f"{k:06d}.png").astype(np.int64) - 1
        by_id = {int(v["id"]): v for v in gt[k]["vehicles"]}
        for vid, _, bbox in _id_boxes(ids):
            if vid not in by_id:
                raise ExportError(f"{drive_dir}: frame {k}: vehicle {vid} seen, not in its record")
            lines.append(kitti_row(k, gt[k], by_id[vid], bbox) + "\n")
    label = out_dir / "kitti" / "label_02" / f"{seq}.txt"
    seqmap = out_dir / "kitti" / "evaluate_tracking.seqmap.training"
    label.parent.mkdir(parents=True, exist_ok=True)
    write_text(label, "".join(lines))
    write_text(seqmap, f"{seq} empty 000000 {len(gt):06d}\n")
    return [label, seqmap]


def _export_coco(drive_dir: Path, out_dir: Path, gt: list[dict], camera, progress: bool) -> Path:
    from pycocotools import mask as mask_utils

    from estimator.fileio import read_png, write_json

    images, annotations = [], []
    for k in _frames(len(gt), "export coco", progress):
        ids = read_png(drive_dir / "ids" / f"{k:06d}.png").astype(np.int64) - 1
        images.append(
            {
                "id": k,
                "file_name": f"frames/{k:06d}.png",
                "width": camera.width,
                "height": camera.height,
                "t_s": gt[k]["t_s"],
            }
        )
        for vid, m, bbox in _id_boxes(ids):
            rle = mask_utils.encode(np.asfortranarray(m.astype(np.uint8)))
            rle["counts"] = rle["counts"].decode("ascii")
            annotations.append(
                {
                    "id": len(annotations) + 1,
                    "image_id": k,
                    "category_id": 1,
                    "track_id": int(vid),
                    "segmentation": rle,
                    "area": int(m.sum()),
                    "bbox": bbox,
                    "iscrowd": 0,
                }
            )
    path = out_dir / "coco.json"
    write_json(
        path,
        {
            "info": {"description": f"omnibench drive {drive_dir.name}: vehicle instances"},
            "images": images,
            "annotations": annotations,
            "categories": [{"id": 1, "name": "vehicle", "supercategory": "vehicle"}],
        },
    )
    return path


def _vehicle_pose(v: dict) -> tuple[np.ndarray, np.ndarray]:
    """(R (3, 3), t (3,)) world from a vehicle's body frame (its yaw about z)."""
    c, s = np.cos(v["yaw_rad"]), np.sin(v["yaw_rad"])
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), np.array(
        [v["x_m"], v["y_m"], 0.0]
    )


def flow_between(
    camera, gt_a: dict, gt_b: dict, ids: np.ndarray, range_m: np.ndarray
) -> np.ndarray:
    """(H, W, 2) float64 flow [px] of frame a's pixels into frame b (module docstring).

    ids: (H, W) vehicle id per pixel (-1 none, 0 the ego car); range_m: (H, W) range
    along each pixel's ray [m] (0: none).
    """
    H, W = ids.shape
    rays = camera.pixel_rays().reshape(-1, 3).astype(np.float64)
    Ta = np.asarray(gt_a["T_world_cam_actual"], float)
    Tb = np.asarray(gt_b["T_world_cam_actual"], float)
    d = rays @ Ta[:3, :3].T  # world directions
    o = Ta[:3, 3]
    r = range_m.reshape(-1).astype(np.float64)
    idv = ids.reshape(-1)
    p = o + d * r[:, None]  # surface points (world)
    with np.errstate(divide="ignore", invalid="ignore"):
        s_road = -o[2] / d[:, 2]
    road = (idv < 0) & (r > 0) & (np.abs(p[:, 2]) < ROAD_Z_M) & (s_road > 0)
    p[road] = o + d[road] * s_road[road, None]  # exactly on the plane z = 0
    known = r > 0
    # vehicles: their rigid motion from a to b
    b_by_id = {v["id"]: v for v in gt_b["vehicles"]}
    for v in gt_a["vehicles"]:
        sel = idv == v["id"]
        if not sel.any():
            continue
        if v["id"] not in b_by_id:
            known &= ~sel
            continue
        Ra, ta = _vehicle_pose(v)
        Rb, tb = _vehicle_pose(b_by_id[v["id"]])
        p[sel] = (p[sel] - ta) @ Ra @ Rb.T + tb  # Rb Ra^T (p - ta) + tb
    ego = idv == 0  # moves with the camera
    p[ego] = (p[ego] - o) @ Ta[:3, :3] @ Tb[:3, :3].T + Tb[:3, 3]
    P_b = (p - Tb[:3, 3]) @ Tb[:3, :3]  # camera b axes: R_b^T (p - o_b)
    w_b = camera.project(P_b)
    ok = known & camera.valid_rays(P_b) & np.all(np.isfinite(w_b), axis=1)
    w_a = camera.pixel_grid().reshape(-1, 2)
    flow = np.where(ok[:, None], w_b - w_a, np.nan)
    return flow.reshape(H, W, 2)


def _export_flow(
    drive_dir: Path, out_dir: Path, gt: list[dict], camera, progress: bool
) -> list[Path]:
    from estimator.fileio import atomic_write, read_png

    (out_dir / "flow").mkdir(exist_ok=True)
    out = []
    for k in _frames(len(gt) - 1, "export flow", progress):
        ids = read_png(drive_dir / "ids" / f"{k:06d}.png").astype(np.int64) - 1
        rng = read_png(drive_dir / "range" / f"{k:06d}.png").astype(np.float64) * RANGE_UNIT_M
        flow = flow_between(camera, gt[k], gt[k + 1], ids, rng)
        p = out_dir / "flow" / f"{k:06d}.npy"
        atomic_write(p, lambda tmp, f=flow: np.save(tmp, f))
        out.append(p)
    return out
