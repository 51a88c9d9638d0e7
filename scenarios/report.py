"""Static HTML pages: one run's metrics, pictures and links to the videos; a recording's
analysis (`omnibench estimate`).

It opens from disk (relative links, no scripts, no network).
"""

from __future__ import annotations

import html
import math
from pathlib import Path

from estimator.fileio import write_text
from scenarios.detection_metrics import MISPLACED_M, UNMATCHED_KINDS

_CSS = """body{font-family:sans-serif;margin:1.5em;max-width:1700px}
table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 8px}
th{background:#eee;text-align:left}img{max-width:100%;border:1px solid #ccc}
.sec{margin-top:1.2em}"""


def _fmt(v) -> str:
    if isinstance(v, float):
        return "nan" if math.isnan(v) else f"{v:.4g}"
    return html.escape(str(v))


def _table(section: dict) -> str:
    rows = "".join(
        f"<tr><th>{html.escape(k)}</th><td>{_fmt(v)}</td></tr>"
        for k, v in section.items()
        if not isinstance(v, dict | list)
    )
    return f"<table>{rows}</table>"


def _rows_table(rows: dict, columns: tuple[str, ...]) -> str:
    """A table with a row per key of rows ({name: {column: value}})."""
    head = "".join(f"<th>{html.escape(c)}</th>" for c in ("", *columns))
    body = "".join(
        f"<tr><th>{html.escape(name)}</th>"
        + "".join(f"<td>{_fmt(row.get(c, ''))}</td>" for c in columns)
        + "</tr>"
        for name, row in rows.items()
    )
    return f"<table><tr>{head}</tr>{body}</table>"


STAGE_COLUMNS = (
    "mask pixel recall",
    "candidate recall",
    "candidate precision",
    "track recall",
    "track precision",
)


def _stage_rows(surround: dict) -> dict:
    """Per range band, each stage's recall (`STAGE_COLUMNS`): {} without the candidates'
    figures (runs written before they were measured)."""
    cand = surround.get("candidates", {}).get("ego_state", {}).get("moving", {})
    trk = surround.get("tracks", {}).get("ego_state", {}).get("moving", {})
    seg = surround.get("segmentation", {}) if isinstance(surround.get("segmentation"), dict) else {}
    if "range_bands" not in cand:
        return {}
    nan = float("nan")
    rows = {}
    for band, c in cand["range_bands"].items():
        t = trk.get("range_bands", {}).get(band, {})
        rows[band] = {
            "mask pixel recall": seg.get("range_bands", {}).get(band, {}).get("pixel_recall", nan),
            "candidate recall": c.get("recall", nan),
            "candidate precision": c.get("precision", nan),
            "track recall": t.get("recall", nan),
            "track precision": t.get("precision", nan),
        }
    return rows


STATE_COLUMNS = (
    "pairs",
    "velocity median [m/s]",
    "velocity p90 [m/s]",
    "heading median [deg]",
    "position NEES mean",
    "position NEES within bound",
    "velocity NEES mean",
    "velocity NEES within bound",
)


def _state_rows(state: dict) -> dict:
    """`STATE_COLUMNS` of `scenarios.track_state.track_state`: all pairs, then by range."""

    def row(s: dict) -> dict:
        v, p, n = s["velocity"], s["position_nees"], s["velocity_nees"]
        return dict(
            zip(
                STATE_COLUMNS,
                (
                    v["pairs"],
                    v["median_error_mps"],
                    v["p90_error_mps"],
                    s["heading"]["median_error_deg"],
                    p["mean"],
                    p["within_95"],
                    n["mean"],
                    n["within_95"],
                ),
                strict=True,
            )
        )

    return {"all": row(state), **{b: row(s) for b, s in state["range_bands"].items()}}


def _surround_section(surround: dict) -> str:
    """Where the tracks fail (`scenarios.detection_metrics.breakdown`): by range band,
    bearing sector, the vehicles' motion and apparent size, and the ego car's state."""
    b = surround.get("tracks", {})
    parts = [
        f"<div class=sec><h2>surround: where the tracks find vehicles</h2>"
        f"<p>{_fmt(surround.get('gt_vehicles'))} distinct vehicles in the evaluation set</p>"
    ]
    cols = ("recall", "precision", "gt_count", "matched", "hyp_count")
    for key, caption in (("range_bands", "by range"), ("sectors", "by bearing")):
        if key in b:
            parts.append(f"<h3>{caption}</h3>{_rows_table(b[key], cols)}")
    if "motion" in b:
        parts.append(
            "<h3>by motion relative to the ego car</h3>"
            + _rows_table(b["motion"], ("recall", "gt_count", "matched"))
        )
    if "sizes" in b:
        parts.append(
            "<h3>by apparent size (COCO's: small below 32² px, medium to 96², large)</h3>"
            + _rows_table(b["sizes"], ("recall", "gt_count", "matched"))
        )
    if "unmatched" in b:
        u = b["unmatched"]
        parts.append(
            "<h3>what the unmatched track points are</h3>"
            + _rows_table(
                {k: {"count": u[k], "share": u[f"{k}_share"]} for k in UNMATCHED_KINDS},
                ("count", "share"),
            )
            + f"<p>{_fmt(u['unmatched'])} of {_fmt(u['hyp_count'])} track points match no "
            f"vehicle: duplicate (within the gate of a vehicle another point matched), "
            f"misplaced (within {MISPLACED_M:g} m of one), clutter (farther from all)</p>"
        )
    if "ego_state" in b:
        rows = {
            state: {
                "frames": v["frames"],
                **v["detection"],
                **{k: v["tracking"][k] for k in ("mota", "idf1", "hota")},
                "median_error_m": v["localization"]["median_error_m"],
            }
            for state, v in b["ego_state"].items()
        }
        cols = ("frames", "recall", "precision", "mota", "idf1", "hota", "median_error_m")
        parts.append(f"<h3>by the ego car's state</h3>{_rows_table(rows, cols)}")
        moving = b["ego_state"].get("moving", {})
        if "range_bands" in moving:
            parts.append(
                "<h3>ego car moving: by range</h3>"
                + _rows_table(moving["range_bands"], ("recall", "precision", "gt_count", "matched"))
                + "<h3>ego car moving: by motion relative to the ego car</h3>"
                + _rows_table(moving["motion"], ("recall", "gt_count", "matched"))
                + "<h3>ego car moving: by apparent size</h3>"
                + _rows_table(moving.get("sizes", {}), ("recall", "gt_count", "matched"))
            )
    stages = _stage_rows(surround)
    if stages:
        parts.append(
            "<h3>ego car moving: where vehicles are lost, stage by stage, by range</h3>"
            + _rows_table(stages, STAGE_COLUMNS)
            + "<p>the mask's share of the vehicles' pixels (every frame); the detector's "
            "candidates (before the tracker decides which are vehicles); the reported "
            "tracks</p>"
        )
    losses = surround.get("tracker")
    if isinstance(losses, dict):
        parts.append(
            "<h3>ego car moving: what the candidates found and the tracks did not</h3>"
            + _rows_table(
                {"vehicle-frames": {**losses["lost_by_track_state"], "all": losses["lost"]}},
                (*losses["lost_by_track_state"], "all"),
            )
            + f"<p>by the state of the found candidate's track, of "
            f"{_fmt(losses['candidates_matched'])} vehicle-frames the candidates found "
            f"(tentative: not yet confirmed; young: too few hits to be a vehicle; "
            f"intermittent: too low a hit rate; vehicle: its reported point elsewhere; none: "
            f"no track); {_fmt(losses['tracks_only'])} found by the tracks only</p>"
        )
    state = surround.get("track_state")
    if isinstance(state, dict):
        parts.append(
            "<h3>the tracks' state against the truth</h3>"
            + _rows_table(_state_rows(state), STATE_COLUMNS)
            + f"<p>of the matched tracks: velocity over the ground, box heading (modulo 180 "
            f"deg), and the NEES of position and velocity (honest covariances: mean 2, a "
            f"share 0.95 within {_fmt(state.get('nees_bound'))}; more: overconfident)</p>"
        )
    seg = surround.get("segmentation")
    if isinstance(seg, dict):
        parts.append(
            "<h3>the motion mask against the vehicles' pixels</h3>"
            f"<p>pixel recall {_fmt(seg.get('pixel_recall'))}, pixel precision "
            f"{_fmt(seg.get('pixel_precision'))} ({_fmt(seg.get('frames'))} frames)</p>"
            + _rows_table(seg.get("range_bands", {}), ("pixel_recall", "vehicle_px"))
        )
    return "".join(parts) + "</div>"


def write_run_report(out_dir: Path, metrics: dict) -> Path:
    """``out_dir/report.html`` for the run whose metrics.json content is ``metrics``."""
    out_dir = Path(out_dir)
    parts = [
        f"<h1>omnibench: {html.escape(str(metrics.get('scenario')))}</h1>",
        f"<p>camera <b>{_fmt(metrics.get('camera'))}</b>, estimator "
        f"<b>{_fmt(metrics.get('estimator'))}</b>, {_fmt(metrics.get('frames'))} frames"
        "</p>",
    ]
    for name in (
        "ego",
        "detection",
        "tracking",
        "localization",
        "compensation",
        "points_above_road",
        "point_pull",
        "timing",
    ):
        if isinstance(metrics.get(name), dict):
            parts.append(f"<div class=sec><h2>{name}</h2>{_table(metrics[name])}</div>")
    if isinstance(metrics.get("surround"), dict):
        parts.append(_surround_section(metrics["surround"]))
    images = (
        ("surround.png", "side-by-side panels (paper Fig. 4)"),
        ("ego_error.png", "ego-motion against ground truth and the CAN prior"),
        ("tracks.png", "track positions against time (paper Fig. 5, 9)"),
        ("recall_polar.png", "track recall around the car, by range and bearing"),
        (
            "segmentation.png",
            "the motion mask against the vehicles' true pixels (yellow: marked vehicle, green: "
            "vehicle not marked, red: marked, no vehicle)",
        ),
        ("pull.png", "where the images pull the estimate off the truth (point_pull)"),
    )
    files = ("analysis.mp4", "drive/drive.mp4", "metrics.json", "egomotion.csv", "tracks.csv")
    return _write_page(out_dir, str(metrics.get("scenario")), parts, images, files)


def _write_page(out_dir: Path, title: str, parts: list[str], images: tuple, files: tuple) -> Path:
    """``out_dir/report.html``: the parts, then each (picture, caption) and a link to each
    file, those that exist in out_dir."""
    parts = list(parts)
    for img, caption in images:
        if (out_dir / img).exists():
            parts.append(f"<div class=sec><h2>{caption}</h2><img src='{img}' alt='{img}'></div>")
    links = [f"<a href='{v}'>{v}</a>" for v in files if (out_dir / v).exists()]
    parts.append("<div class=sec><h2>files</h2><p>" + " · ".join(links) + "</p></div>")
    page = (
        f"<!doctype html><html><head><meta charset='utf-8'><title>omnibench "
        f"{html.escape(title)}</title><style>{_CSS}</style></head>"
        f"<body>{''.join(parts)}</body></html>\n"
    )
    path = out_dir / "report.html"
    write_text(path, page)
    return path


def write_recording_report(out_dir: Path, summary: dict) -> Path:
    """``out_dir/report.html`` for the analysis of a recording (`omnibench estimate`):
    the summary's figures, the pictures and links to the files that exist."""
    name = str(summary.get("recording"))
    parts = [f"<h1>omnibench: {html.escape(name)}</h1>", f"<div class=sec>{_table(summary)}</div>"]
    images = (
        ("egomotion.png", "ego-motion against time, beside the CAN speed"),
        ("surround.png", "side-by-side panels (paper Fig. 4)"),
        ("tracks.png", "track positions against time (paper Fig. 5, 9)"),
    )
    files = ("analysis.mp4", "egomotion.csv", "tracks.csv")
    return _write_page(Path(out_dir), name, parts, images, files)
