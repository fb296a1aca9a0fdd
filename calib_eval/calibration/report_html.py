"""``report.html`` beside camchain.yaml: the calibration as a person looks at it.

Self-contained (plots embedded as PNG): the verdict and per-camera RMS; per camera the residual
vectors over the image and their histogram, the coverage of the image circle by the used
corners, the conditioning trajectory gamma_k of stage 1 and the dropped views; per camera pair
the extrinsics and their spread over the shared views; and the capture advice of
:mod:`calib_eval.calibration.coverage`.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np
import torch
from torch import Tensor

from calib_eval.calibration.calibrator import CalibrationResult
from calib_eval.calibration.coverage import RINGS, coverage
from calib_eval.calibration.initialisation import view_pose
from calib_eval.calibration.solver import Problem, solve
from cotrain.geometry import cameras, rotation_angle_deg
from cotrain.io.sequence import Observation, Sequence


def residuals(res: CalibrationResult, seq: Sequence) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per camera: corner pixels (M, 2), residual vectors observed - predicted (M, 2) and (M,) which
    corners the calibration rejected as outliers, over the observations whose view it kept."""
    P = seq.target.points().numpy()
    out = []
    for c in range(len(seq.cameras)):
        qs, rs, xs = [], [], []
        for o in seq.by_camera(c):
            T_rb = res.T_rig_board.get(o.view)
            if T_rb is None:
                continue
            T = res.T_cam_rig[c] @ T_rb
            pc = P[o.ids] @ T[:3, :3].T + T[:3, 3]
            q, ok = cameras.project(res.model[c], torch.from_numpy(pc), torch.from_numpy(np.asarray(res.intrinsics[c], np.float64)))
            ok = ok.numpy()
            qs.append(o.q[ok])
            rs.append(o.q[ok] - q.numpy()[ok])
            xs.append(np.isin(o.ids, res.rejected.get((c, o.view), []))[ok])
        if not qs:
            out.append((np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool)))
            continue
        out.append((np.concatenate(qs), np.concatenate(rs), np.concatenate(xs)))
    return out


def anchor_spans(seq: Sequence, anchors: dict[int, list[int]]) -> dict[int, tuple[int, float, float]]:
    """Per camera: the number of anchor views and the radial span (lowest, highest corner radius,
    fractions of the image radius R of :func:`coverage`) their corners cover together."""
    cov = coverage(seq)
    out = {}
    for c, views in anchors.items():
        obs = [o for o in seq.by_camera(c) if o.view in set(views)]
        r = np.concatenate([cov.cameras[c].radius_of(o.q) for o in obs]) if obs else np.zeros(0)
        out[c] = (len(obs), float(r.min()), float(r.max())) if len(r) else (0, math.nan, math.nan)
    return out


def view_pose_refined(model: str, intr: Tensor, o: Observation, target) -> np.ndarray | None:
    """T_cam_board of one observation alone: the bearing pose refined on the reprojection error
    with the calibrated intrinsics fixed."""
    T0 = view_pose(model, intr, o, target)
    if T0 is None:
        return None
    prob = Problem.build([o], target, {o.view: 0}, single_camera=True)
    _, _, Tb, _ = solve(
        prob, [model], [intr], torch.eye(4, dtype=torch.float64)[None], torch.from_numpy(T0)[None], opt_intr=False, iters=10
    )
    return Tb[0].numpy()


def pair_spread(res: CalibrationResult, seq: Sequence) -> dict[tuple[int, int], tuple[float, float, int]]:
    """Per camera pair (a, b): the spread (median deviation, mm and deg) from the calibrated
    relative pose of the one each shared view implies alone (each camera's pose of that view
    fitted to its corners with the calibrated intrinsics), and the number of shared views."""
    per_cam = [{o.view: o for o in seq.by_camera(c) if o.view in res.T_rig_board} for c in range(len(seq.cameras))]
    intr = [torch.from_numpy(np.asarray(x, np.float64)) for x in res.intrinsics]
    out = {}
    for a in range(len(seq.cameras)):
        for b in range(a + 1, len(seq.cameras)):
            shared = sorted(set(per_cam[a]) & set(per_cam[b]))
            T_ba = res.T_cam_rig[b] @ np.linalg.inv(res.T_cam_rig[a])
            dt, dr = [], []
            for v in shared:
                Ta = view_pose_refined(res.model[a], intr[a], per_cam[a][v], seq.target)
                Tb = view_pose_refined(res.model[b], intr[b], per_cam[b][v], seq.target)
                if Ta is None or Tb is None:
                    continue
                D = np.linalg.inv(T_ba) @ (Tb @ np.linalg.inv(Ta))
                dt.append(1000 * np.linalg.norm(D[:3, 3]))
                dr.append(float(rotation_angle_deg(torch.from_numpy(D[:3, :3]))))
            out[(a, b)] = (float(np.median(dt)) if dt else math.nan, float(np.median(dr)) if dr else math.nan, len(shared))
    return out


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    return f'<img alt="plot" src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}">'


def write_report_html(res: CalibrationResult, seq: Sequence, out_dir: str | Path, anchors: dict[int, list[int]] | None = None) -> Path:
    """Write ``out_dir/report.html``; returns its path. ``anchors``: per camera, the selector's
    anchor views (their radial span is shown)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    cov = coverage(seq)
    empty = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool))
    res_per_cam = residuals(res, seq) if res.T_rig_board else [empty] * len(seq.cameras)
    spans = anchor_spans(seq, anchors) if anchors else {}
    e = html.escape
    verdict = "succeeded" if res.success else f"failed: {res.reason}"
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>calibration report</title><style>"
        "body{font-family:sans-serif;margin:2em;max-width:75em}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}.advice li{margin:.3em 0}"
        ".row{display:flex;flex-wrap:wrap;gap:1em}</style></head><body>",
        f"<h1>Calibration {e(verdict)}</h1>",
        f"<p>{len(seq.cameras)} cameras, {seq.n_views} views, target: {e(str(seq.target))}; run time {res.runtime_s:.1f} s.</p>",
        "<h2>What to capture next</h2><ul class='advice'>",
        *(f"<li>{e(a)}</li>" for a in cov.advice),
        "</ul>" if cov.advice else "<li>nothing: every camera is seen to its rim all round, and every camera is linked</li></ul>",
        "<h2>Cameras</h2><table><tr><th>camera</th><th>model</th><th>RMS px</th><th>views used</th><th>corners rejected</th>"
        "<th>out to (of R)</th><th>widest single view (of R)</th><th>anchors: views, radial span (of R)</th></tr>",
    ]
    used = res.frames_per_stage.get("full", [0] * len(seq.cameras))
    for c, info in enumerate(seq.cameras):
        rms = res.rms_px[c] if c < len(res.rms_px) else math.nan
        cc = cov.cameras[c]
        n_rej = int(res_per_cam[c][2].sum())
        span = f"{spans[c][0]}, {spans[c][1]:.2f} - {spans[c][2]:.2f}" if c in spans else "no selection"
        parts.append(
            f"<tr><td>{e(info.name)}</td><td>{e(res.model[c])}</td><td>{rms:.3f}</td>"
            f"<td>{used[c] if c < len(used) else 0}</td><td>{n_rej}</td><td>{cc.max_radius:.2f}</td>"
            f"<td>{cc.widest_view:.2f}</td><td>{span}</td></tr>"
        )
    parts.append("</table>")
    for c, info in enumerate(seq.cameras):
        q_all, r_all, rej = res_per_cam[c]
        q, r = q_all[~rej], r_all[~rej]
        parts.append(f"<h3>{e(info.name)}</h3><div class='row'>")
        fig, ax = plt.subplots(figsize=(6, 3.6))
        if len(q):
            scale = 20.0
            ax.quiver(
                q[:, 0],
                q[:, 1],
                r[:, 0],
                r[:, 1],
                np.linalg.norm(r, axis=1),
                angles="xy",
                scale_units="xy",
                scale=1 / scale,
                cmap="viridis",
            )
        if rej.any():
            ax.scatter(q_all[rej, 0], q_all[rej, 1], s=12, marker="x", color="red", label=f"rejected as outliers ({int(rej.sum())})")
            ax.legend(loc="lower right", fontsize=7)
        ax.set_xlim(0, info.width)
        ax.set_ylim(info.height, 0)
        ax.set_aspect("equal")
        ax.set_title("residual vectors (x20) of the corners used")
        parts.append(_png(fig))
        plt.close(fig)
        fig, ax = plt.subplots(figsize=(4, 3.6))
        ax.hist(np.linalg.norm(r, axis=1), bins=40, color="tab:blue")
        ax.set_xlabel("residual (px)")
        ax.set_title("residuals of the corners used")
        parts.append(_png(fig))
        plt.close(fig)
        fig, ax = plt.subplots(figsize=(4.2, 3.6))
        cc = cov.cameras[c]
        pts = np.concatenate([o.q for o in seq.by_camera(c)]) if seq.by_camera(c) else np.zeros((0, 2))
        ax.scatter(pts[:, 0], pts[:, 1], s=1, alpha=0.3)
        for f in RINGS[1:]:
            ax.add_patch(plt.Circle(((info.width - 1) / 2, (info.height - 1) / 2), f * cc.R, fill=False, ls="--", color="gray"))
        ax.set_xlim(0, info.width)
        ax.set_ylim(info.height, 0)
        ax.set_aspect("equal")
        ax.set_title(f"coverage: out to {cc.max_radius:.2f} R")
        parts.append(_png(fig))
        plt.close(fig)
        if c < len(res.gamma) and res.gamma[c]:
            fig, ax = plt.subplots(figsize=(4, 3.6))
            ax.plot(range(1, len(res.gamma[c]) + 1), res.gamma[c], "o-")
            ax.set_xlabel("initialisation step k")
            ax.set_ylabel("gamma_k")
            ax.set_title("conditioning of stage 1")
            parts.append(_png(fig))
            plt.close(fig)
        parts.append("</div>")
    parts.append(
        "<h2>Camera pairs</h2><table><tr><th>pair</th><th>baseline mm</th><th>rotation deg</th>"
        "<th>shared views</th><th>spread mm / deg</th></tr>"
    )
    spread = pair_spread(res, seq) if res.T_rig_board else {}
    for (a, b), (dt, dr, n) in spread.items():
        T = res.T_cam_rig[b] @ np.linalg.inv(res.T_cam_rig[a])
        rot = float(rotation_angle_deg(torch.from_numpy(T[:3, :3])))
        parts.append(
            f"<tr><td>{e(seq.cameras[a].name)} - {e(seq.cameras[b].name)}</td><td>{1000 * np.linalg.norm(T[:3, 3]):.2f}</td>"
            f"<td>{rot:.3f}</td><td>{n}</td><td>{dt:.2f} / {dr:.3f}</td></tr>"
        )
    parts.append("</table><p>Spread: median deviation of the relative pose each shared view implies alone from the calibrated one.</p>")
    parts.append(f"<h2>Dropped views ({len(res.dropped)})</h2>")
    if res.dropped:
        parts.append("<table><tr><th>view</th><th>frame</th><th>cameras</th><th>reason</th></tr>")
        for d in res.dropped:
            parts.append(
                f"<tr><td>{d['view']}</td><td>{e(str(d['frame']))}</td><td>{e(', '.join(d['cameras']))}</td><td>{e(d['reason'])}</td></tr>"
            )
        parts.append("</table>")
    parts.append("</body></html>")
    path = Path(out_dir) / "report.html"
    path.write_text("\n".join(parts))
    return path
