"""Pictures of a run: the side-by-side video panels (paper Fig. 4), track plots
(Fig. 5, 9) and the surround map.

Panels, each ``PANEL_PX`` square:
(a) the frame with the estimated road motion (arrows) and the estimator's
    points: inliers grey, outliers white, unused black (Fig. 4a-b);
(c) the normalized frame difference after compensation (Fig. 4c);
(d) detections with track ids and road-plane coordinates (Fig. 4d);
(e) the surround plan view with vehicles and their tracks (Fig. 4e).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from estimator.egomotion.homography import homography
from estimator.surround.planview import PlanView

PANEL_PX = 400
INLIER, OUTLIER = 1, 2  # labels of EgoMotionRecord.point_labels (0 = unused)


def _fit(img: np.ndarray) -> np.ndarray:
    if img.ndim == 2:
        img = cv2.cvtColor(img, cv2.COLOR_GRAY2RGB)
    h, w = img.shape[:2]
    s = PANEL_PX / max(h, w)
    img = cv2.resize(img, (int(round(w * s)), int(round(h * s))), interpolation=cv2.INTER_AREA)
    out = np.zeros((PANEL_PX, PANEL_PX, 3), np.uint8)
    y0, x0 = (PANEL_PX - img.shape[0]) // 2, (PANEL_PX - img.shape[1]) // 2
    out[y0 : y0 + img.shape[0], x0 : x0 + img.shape[1]] = img
    return out


def _label(img: np.ndarray, text: str) -> np.ndarray:
    cv2.putText(img, text, (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 0), 1, cv2.LINE_AA)
    return img


def motion_panel(
    image: np.ndarray, rec, camera, K0: np.ndarray, grid_px: int = 40, gain: float = 1.0
) -> np.ndarray:
    """(a)+(b): frame with estimated road-motion arrows and classified points."""
    out = image.copy()
    pts = getattr(rec, "points_px", np.zeros((0, 2)))
    labels = getattr(rec, "point_labels", np.zeros(0))
    colours = {0: (0, 0, 0), INLIER: (150, 150, 150), OUTLIER: (255, 255, 255)}
    for lab, col in colours.items():
        for u, v in pts[labels == lab].astype(int):
            cv2.circle(out, (int(u), int(v)), 1, col, -1)
    dt = getattr(rec, "dt_s", 0.0)
    if dt and np.all(np.isfinite(rec.x)):
        H = homography(np.asarray(rec.x, float), K0, dt)
        vv, uu = np.mgrid[
            grid_px // 2 : camera.height : grid_px, grid_px // 2 : camera.width : grid_px
        ]
        w_a = np.stack([uu.ravel(), vv.ravel()], axis=1).astype(float)
        rays = camera.unproject(w_a)
        road = camera.valid_rays(rays) & (rays @ K0 > 0)
        w_b = camera.project(rays[road] @ H.T)
        for p, q in zip(w_a[road], w_b, strict=True):
            if np.all(np.isfinite(q)):
                q = p + gain * (q - p)
                cv2.arrowedLine(
                    out,
                    tuple(int(c) for c in p),
                    tuple(int(c) for c in q),
                    (255, 40, 40),
                    1,
                    cv2.LINE_AA,
                    tipLength=0.3,
                )
    return _label(_fit(out), "(a) ego-motion, points in/out/unused")


def difference_panel(nd: np.ndarray, valid: np.ndarray, scale: float = 3.0) -> np.ndarray:
    """(c): |normalized difference| as an image."""
    img = np.clip(np.abs(nd) * (255.0 / scale), 0, 255).astype(np.uint8)
    img[~valid] = 0
    img = cv2.applyColorMap(img, cv2.COLORMAP_INFERNO)[..., ::-1]
    return _label(_fit(img), "(c) normalized difference")


def detection_panel(image: np.ndarray, sframe) -> np.ndarray:
    """(d): detections (nearest road point) with track ids and road coordinates."""
    out = image.copy()
    out[sframe.detection.motion_mask] = (
        0.5 * out[sframe.detection.motion_mask] + [0, 110, 0]
    ).astype(np.uint8)
    by_det = {id(t.extra): t for t in sframe.tracks if getattr(t, "extra", None) is not None}
    for d in sframe.detection.detections:
        if not np.all(np.isfinite(d.pixel)):
            continue
        u, v = int(d.pixel[0]), int(d.pixel[1])
        cv2.circle(out, (u, v), 5, (255, 255, 0), 2)
        t = by_det.get(id(d))
        txt = (f"#{t.id} " if t else "") + f"{d.x_m:+.1f},{d.y_m:+.1f}"
        cv2.putText(
            out, txt, (u + 6, v - 4), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (255, 255, 0), 1, cv2.LINE_AA
        )
    return _label(_fit(out), "(d) detections: track id, x,y [m]")


SEGMENTATION_COLOURS = {  # RGB of the motion mask's audit picture
    "marked vehicle": (255, 220, 0),
    "vehicle not marked": (0, 210, 0),
    "marked, no vehicle": (235, 0, 0),
}


def segmentation_picture(
    image: np.ndarray, mask: np.ndarray, vehicles: np.ndarray, area: np.ndarray
) -> np.ndarray:
    """(H, W, 3) uint8 RGB: the motion mask against the vehicles' true pixels over the
    detector's analysed area (`scenarios.segmentation`), in `SEGMENTATION_COLOURS` over the
    dimmed image (darker outside the area). image (H, W, 3) RGB uint8; mask, vehicles,
    area: (H, W) bool."""
    mask, vehicles, area = (np.asarray(a, bool) for a in (mask, vehicles, area))
    out = np.asarray(image, np.float32) * 0.6
    out[~area] *= 0.4
    masks = (mask & vehicles, ~mask & vehicles, mask & ~vehicles)
    for sel, rgb in zip(masks, SEGMENTATION_COLOURS.values(), strict=True):
        sel = sel & area
        out[sel] = 0.3 * out[sel] + 0.7 * np.asarray(rgb, np.float32)
    out = np.clip(out, 0, 255).astype(np.uint8)
    for i, (name, rgb) in enumerate(SEGMENTATION_COLOURS.items()):
        cv2.putText(out, name, (6, 18 + 18 * i), cv2.FONT_HERSHEY_SIMPLEX, 0.5, rgb, 1, cv2.LINE_AA)
    return out


def surround_panel(
    image: np.ndarray, plan: PlanView, tracks, gt_xy: np.ndarray | None = None
) -> np.ndarray:
    """(e): plan view of the road around the car with tracks (and ground truth dots)."""
    top = plan.warp(image)
    top[~plan.seen] = (top[~plan.seen] * 0.3).astype(np.uint8)
    c = plan.to_pixel(np.zeros((1, 2)))[0].astype(int)
    cv2.rectangle(top, (c[0] - 10, c[1] - 25), (c[0] + 10, c[1] + 25), (240, 150, 50), 2)
    if gt_xy is not None and len(gt_xy):
        for q in plan.to_pixel(gt_xy).astype(int):
            cv2.circle(top, (int(q[0]), int(q[1])), 4, (0, 255, 0), -1)
    for t in tracks:
        hist = np.array([(x, y) for _, x, y in t.history[-30:]]).reshape(-1, 2)
        if len(hist) > 1:
            pts = plan.to_pixel(hist).astype(np.int32)
            cv2.polylines(top, [pts], False, (255, 200, 0), 1, cv2.LINE_AA)
        q = plan.to_pixel(np.array(t.x[:2]))[0].astype(int)
        cv2.circle(top, (int(q[0]), int(q[1])), 6, (255, 60, 60), 2)
        cv2.putText(
            top,
            f"#{t.id}",
            (int(q[0]) + 7, int(q[1])),
            cv2.FONT_HERSHEY_SIMPLEX,
            0.45,
            (255, 255, 255),
            1,
            cv2.LINE_AA,
        )
    title = "(e) surround map: tracks (red)" + (", truth (green)" if gt_xy is not None else "")
    return _label(_fit(top), title)


def plot_tracks(rows: list[tuple], path: Path, title: str = "") -> None:
    """Longitudinal position of each track against time, left and right side (Fig. 5, 9).

    rows: (frame, t_s, track_id, x_m, y_m, ...) in the ego road frame.
    """
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.fileio import atomic_write

    fig, axes = plt.subplots(1, 2, figsize=(10, 4), sharey=True)
    arr = np.array([r[:5] for r in rows], float).reshape(-1, 5)
    for ax, side, sel in (
        (axes[0], "left (y > 0)", arr[:, 4] > 0),
        (axes[1], "right (y < 0)", arr[:, 4] <= 0),
    ):
        for tid in np.unique(arr[sel, 2]):
            m = sel & (arr[:, 2] == tid)
            ax.plot(arr[m, 1], arr[m, 3], ".-", ms=3, lw=1, label=f"#{int(tid)}")
        ax.set_title(f"tracks on the {side}")
        ax.set_xlabel("time [s]")
        ax.axhline(0, color="k", lw=0.5)
        ax.grid(alpha=0.3)
    axes[0].set_ylabel("longitudinal position x [m] (ahead > 0)")
    fig.suptitle(title)
    fig.tight_layout()
    atomic_write(path, lambda p: fig.savefig(p, dpi=90), suffix=".png")
    plt.close(fig)


def plot_recall_polar(polar: dict, path: Path, title: str = "") -> None:
    """Recall around the car (`scenarios.detection_metrics.recall_polar`): a polar grid,
    ahead up and left to the left, each cell coloured by its recall and labelled with
    its vehicle-frames (grey: no vehicle there)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from estimator.fileio import atomic_write

    r_edges = np.asarray(polar["range_edges_m"], float)
    b_edges = np.radians(np.asarray(polar["bearing_edges_deg"], float))
    gt = np.asarray(polar["gt_count"], float)
    hit = np.asarray(polar["matched"], float)
    with np.errstate(invalid="ignore", divide="ignore"):
        recall = np.where(gt > 0, hit / np.maximum(gt, 1), np.nan)
    fig = plt.figure(figsize=(5.6, 5.2))
    ax = fig.add_subplot(projection="polar")
    ax.set_theta_zero_location("N")  # bearing 0 (ahead) up, +90 (left) to the left
    ax.set_facecolor("#dddddd")
    cmap = plt.get_cmap("RdYlGn").with_extremes(bad="#dddddd")
    B, Rr = np.meshgrid(b_edges, r_edges)
    mesh = ax.pcolormesh(B, Rr, np.ma.masked_invalid(recall), cmap=cmap, vmin=0, vmax=1)
    for i in range(gt.shape[0]):
        for j in range(gt.shape[1]):
            if gt[i, j] > 0:
                ax.text(
                    0.5 * (b_edges[j] + b_edges[j + 1]),
                    0.5 * (r_edges[i] + r_edges[i + 1]),
                    f"{int(gt[i, j])}",
                    ha="center",
                    va="center",
                    fontsize=6,
                )
    ax.set_thetagrids([0, 90, 180, 270], ["ahead", "left", "behind", "right"])
    ax.set_ylim(0, r_edges[-1])
    ax.set_yticks(r_edges[1:])
    ax.set_yticklabels([f"{r:g} m" for r in r_edges[1:]], fontsize=7)
    fig.colorbar(mesh, ax=ax, shrink=0.7, pad=0.12, label="recall")
    ax.set_title(title or "recall around the car (labels: vehicle-frames)", fontsize=9)
    fig.tight_layout()
    atomic_write(path, lambda p: fig.savefig(p, dpi=90), suffix=".png")
    plt.close(fig)
