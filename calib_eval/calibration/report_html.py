"""``report.html`` beside camchain.yaml: the calibration as a person looks at it.

Self-contained (plots embedded as PNG). It leads with the verdict and its causes
(:mod:`calib_eval.calibration.trust`), then the figures behind it (noise, cross-validation, board
warp, time offsets), the capture advice of :mod:`calib_eval.calibration.coverage`, per camera the
intrinsics with their sigma, the projection-uncertainty map, the map of the difference between
two halves' calibrations, the residual vectors and their histogram and the coverage of the image
circle; per camera pair the extrinsics with their sigma; the dropped views; and, in an appendix,
the conditioning trajectory gamma_k of stage 1.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path

import numpy as np

from calib_eval.calibration.calibrator import CalibrationResult
from calib_eval.calibration.coverage import RINGS, coverage
from cotrain.geometry import cameras, rotation_angle_deg
from cotrain.io.sequence import Sequence
from cotrain.targets import board_points


def residuals(res: CalibrationResult, seq: Sequence) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per camera: corner pixels (M, 2), residual vectors observed - predicted (M, 2) and (M,) which
    corners the calibration rejected as outliers, over the observations whose view it kept."""
    P = board_points(seq.target)
    out = []
    for c in range(len(seq.cameras)):
        qs, rs, xs = [], [], []
        for o in seq.by_camera(c):
            T_rb = res.T_rig_board.get(o.view)
            if T_rb is None:
                continue
            T = res.T_cam_rig[c] @ T_rb
            pc = P[o.ids] @ T[:3, :3].T + T[:3, 3]
            q, ok = cameras.project(res.model[c], pc, np.asarray(res.intrinsics[c], np.float64))
            qs.append(o.q[ok])
            rs.append(o.q[ok] - q[ok])
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


def shared_views(res: CalibrationResult, seq: Sequence) -> dict[tuple[int, int], int]:
    """Per camera pair (a, b): the number of calibrated views both saw the board in."""
    seen = [{o.view for o in seq.by_camera(c) if o.view in res.T_rig_board} for c in range(len(seq.cameras))]
    return {(a, b): len(seen[a] & seen[b]) for a in range(len(seen)) for b in range(a + 1, len(seen))}


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    return f'<img alt="plot" src="data:image/png;base64,{base64.b64encode(buf.getvalue()).decode()}">'


def _heatmap(ax, xs, ys, z, title: str, width: int, height: int) -> None:
    """A per-pixel map (px) with labelled contours, over the image."""
    import numpy as np

    finite = z[np.isfinite(z)]
    im = ax.imshow(z, extent=(xs[0], xs[-1], ys[-1], ys[0]), cmap="magma_r", origin="upper", vmin=0)
    if len(finite) and finite.max() > finite.min():
        levels = np.unique(np.round(np.quantile(finite, [0.25, 0.5, 0.75, 0.95]), 3))
        if len(levels) > 1:
            cs = ax.contour(xs, ys, z, levels=levels, colors="k", linewidths=0.6)
            ax.clabel(cs, fmt="%.3g", fontsize=7)
    ax.figure.colorbar(im, ax=ax, shrink=0.8, label="px")
    ax.set_xlim(0, width)
    ax.set_ylim(height, 0)
    ax.set_aspect("equal")
    ax.set_title(title, fontsize=9)


def _verdict_section(rep, res: CalibrationResult) -> list[str]:
    e = html.escape
    colour = {"trust": "#2e7d32", "caution": "#b26a00", "fail": "#c62828"}[rep.verdict.level]
    parts = [f"<h1 style='color:{colour}'>Verdict: {e(rep.verdict.level)}</h1>"]
    if rep.verdict.causes:
        parts.append("<ul class='causes'>")
        for c in rep.verdict.causes:
            who = f"{e(c.camera)}: " if c.camera and not c.text.startswith(c.camera) else ""
            parts.append(f"<li><b>{e(c.code)}</b> {who}{e(c.text)}</li>")
        parts.append("</ul>")
    elif res.success:
        parts.append(
            "<p>No cause for doubt found: the uncertainty is within the stated use, two halves of the views agree as "
            "their uncertainty predicts, the board is flat, the cameras are synchronised and the model fits.</p>"
        )
    return parts


def _trust_section(rep, res: CalibrationResult, seq: Sequence) -> list[str]:
    """The figures behind the verdict: noise, cross-validation, board, time offsets."""
    e = html.escape
    parts = ["<h2>How far to trust it</h2><table>"]
    u, cv = rep.uncertainty, rep.cross_validation
    if u is not None:
        parts.append(f"<tr><th>corner noise (measured)</th><td>{u.sigma_px:.3f} px per coordinate</td></tr>")
    if cv is not None and cv.ok:
        parts.append(
            f"<tr><th>cross-validation</th><td>two halves of the views differ {cv.spread_ratio:.2f} times as much as their "
            "uncertainty predicts (1: as predicted)</td></tr>"
        )
    elif cv is not None:
        parts.append(f"<tr><th>cross-validation</th><td>not possible: {e(cv.reason)}</td></tr>")
    if res.final is not None and res.final.free.warp and u is not None and u.warp_sigma_m is not None:
        w, s = res.warp_m * 1000, u.warp_sigma_m * 1000
        parts.append(
            f"<tr><th>board warp at its centre</th><td>x {w[0]:+.2f} &plusmn; {s[0]:.2f} mm, y {w[1]:+.2f} &plusmn; {s[1]:.2f} mm</td></tr>"
        )
    for est in res.time_offset_estimates:
        if est.value_s is None:
            txt = f"not estimable: {e(est.reason)}"
        else:
            txt = (
                f"{est.value_s * 1000:+.2f} &plusmn; {est.sigma_s * 1000:.2f} ms ({est.views} views; the board moves {est.shift_px:.2f} px)"
            )
        applied = res.time_offsets_s is not None and any(res.time_offsets_s != 0)
        parts.append(f"<tr><th>{e(est.camera)} time offset to cam0</th><td>{txt}{' (applied)' if applied else ''}</td></tr>")
    parts.append("</table>")
    return parts


def write_report_html(
    res: CalibrationResult, seq: Sequence, out_dir: str | Path, anchors: dict[int, list[int]] | None = None, trust=None
) -> Path:
    """Write ``out_dir/report.html``; returns its path. ``anchors``: per camera, the selector's
    anchor views (their radial span is shown); ``trust``: the :class:`TrustReport` (verdict first)."""
    import matplotlib

    matplotlib.use("Agg")

    cov = coverage(seq)
    empty = (np.zeros((0, 2)), np.zeros((0, 2)), np.zeros(0, bool))
    res_per_cam = residuals(res, seq) if res.T_rig_board else [empty] * len(seq.cameras)
    e = html.escape
    parts = [
        "<!doctype html><html><head><meta charset='utf-8'><title>calibration report</title><style>"
        "body{font-family:sans-serif;margin:2em;max-width:75em}table{border-collapse:collapse}"
        "td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}.advice li,.causes li{margin:.3em 0}"
        ".row{display:flex;flex-wrap:wrap;gap:1em}</style></head><body>",
    ]
    if trust is not None:
        parts += _verdict_section(trust, res)
    verdict = "succeeded" if res.success else f"failed: {res.reason}"
    parts.append(
        f"<p>Calibration {e(verdict)}. {len(seq.cameras)} cameras, {seq.n_views} views, target: {e(str(seq.target))}; "
        f"run time {res.runtime_s:.1f} s.</p>"
    )
    if trust is not None:
        parts += _trust_section(trust, res, seq)
    parts += ["<h2>What to capture next</h2><ul class='advice'>", *(f"<li>{e(a)}</li>" for a in cov.advice)]
    parts.append("</ul>" if cov.advice else "<li>nothing: every camera is seen to its rim all round, and every camera is linked</li></ul>")
    parts += _camera_table(res, seq, cov, res_per_cam, anchors, trust)
    for c in range(len(seq.cameras)):
        parts += _camera_plots(res, seq, cov, res_per_cam[c], c, trust)
    parts += _pair_section(res, seq, trust)
    parts += _dropped_section(res)
    parts.append(
        "<h2>Appendix: conditioning of the initialisation</h2><p>gamma_k is log10 of the condition number of the intrinsics' "
        "information after the board poses are eliminated, at each step of the progressive initialisation: high values mean "
        "the focal length and the lens shape were hard to tell apart from the views used so far (the paper's Sec. III).</p>"
    )
    parts += _gamma_plots(res, seq)
    parts.append("</body></html>")
    path = Path(out_dir) / "report.html"
    path.write_text("\n".join(parts))
    return path


def _camera_table(res, seq, cov, res_per_cam, anchors, trust) -> list[str]:
    e = html.escape
    spans = anchor_spans(seq, anchors) if anchors else {}
    u = trust.uncertainty if trust is not None else None
    parts = [
        "<h2>Cameras</h2><table><tr><th>camera</th><th>model</th><th>RMS px</th><th>views used</th><th>corners rejected</th>"
        "<th>out to (of R)</th><th>widest single view (of R)</th><th>anchors: views, radial span (of R)</th>"
        "<th>projection sigma px (median / 95 %)</th></tr>"
    ]
    used = res.frames_per_stage.get("full", [0] * len(seq.cameras))
    for c, info in enumerate(seq.cameras):
        rms = res.rms_px[c] if c < len(res.rms_px) else math.nan
        cc = cov.cameras[c]
        n_rej = int(res_per_cam[c][2].sum())
        span = f"{spans[c][0]}, {spans[c][1]:.2f} - {spans[c][2]:.2f}" if c in spans else "no selection"
        ps = f"{u.projection[c].median_px:.3f} / {u.projection[c].p95_px:.3f}" if u is not None else "-"
        parts.append(
            f"<tr><td>{e(info.name)}</td><td>{e(res.model[c])}</td><td>{rms:.3f}</td>"
            f"<td>{used[c] if c < len(used) else 0}</td><td>{n_rej}</td><td>{cc.max_radius:.2f}</td>"
            f"<td>{cc.widest_view:.2f}</td><td>{span}</td><td>{ps}</td></tr>"
        )
    parts.append("</table>")
    if u is not None:
        parts.append("<table><tr><th>camera</th><th>intrinsics (Kalibr order) &plusmn; 1 sigma</th></tr>")
        for c, info in enumerate(seq.cameras):
            names = cameras.get_model(res.model[c]).param_names
            vals = ", ".join(f"{n} {v:.4g} &plusmn; {s:.2g}" for n, v, s in zip(names, res.intrinsics[c], u.intrinsics_sigma[c]))
            parts.append(f"<tr><td>{e(info.name)}</td><td style='text-align:left'>{vals}</td></tr>")
        parts.append("</table>")
    return parts


def _camera_plots(res, seq, cov, per_cam, c: int, trust) -> list[str]:
    import matplotlib.pyplot as plt

    info = seq.cameras[c]
    q_all, r_all, rej = per_cam
    q, r = q_all[~rej], r_all[~rej]
    parts = [f"<h3>{html.escape(info.name)}</h3><div class='row'>"]
    if trust is not None and trust.uncertainty is not None:
        m = trust.uncertainty.projection[c]
        fig, ax = plt.subplots(figsize=(6, 3.6))
        _heatmap(ax, m.xs, m.ys, m.sigma_px, "projection uncertainty, 1 sigma (px), where corners were seen", info.width, info.height)
        parts.append(_png(fig))
        plt.close(fig)
    cv = trust.cross_validation if trust is not None else None
    if cv is not None and cv.ok:
        d = cv.projection[c]
        fig, ax = plt.subplots(figsize=(6, 3.6))
        _heatmap(
            ax,
            d.xs,
            d.ys,
            d.diff_px,
            f"two halves of the views: projection difference (px; predicted median {d.predicted_median_px:.3f})",
            info.width,
            info.height,
        )
        parts.append(_png(fig))
        plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 3.6))
    if len(q):
        ax.quiver(
            q[:, 0], q[:, 1], r[:, 0], r[:, 1], np.linalg.norm(r, axis=1), angles="xy", scale_units="xy", scale=1 / 20.0, cmap="viridis"
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
    parts.append("</div>")
    return parts


def _gamma_plots(res, seq) -> list[str]:
    import matplotlib.pyplot as plt

    parts = ["<div class='row'>"]
    for c, info in enumerate(seq.cameras):
        if c < len(res.gamma) and res.gamma[c]:
            fig, ax = plt.subplots(figsize=(4, 3.2))
            ax.plot(range(1, len(res.gamma[c]) + 1), res.gamma[c], "o-")
            ax.set_xlabel("initialisation step k")
            ax.set_ylabel("gamma_k")
            ax.set_title(f"{info.name}: conditioning of stage 1")
            parts.append(_png(fig))
            plt.close(fig)
    parts.append("</div>")
    return parts


def _pair_section(res, seq, trust) -> list[str]:
    e = html.escape
    u = trust.uncertainty if trust is not None else None
    cv = trust.cross_validation if trust is not None and trust.cross_validation is not None and trust.cross_validation.ok else None
    parts = [
        "<h2>Camera pairs</h2><table><tr><th>pair</th><th>baseline mm</th><th>rotation deg</th><th>translation sigma mm</th>"
        "<th>rotation sigma deg</th><th>halves differ by mm / deg (predicted sigma)</th><th>shared views</th></tr>"
    ]
    for (a, b), n in (shared_views(res, seq) if res.T_rig_board else {}).items():
        T = res.T_cam_rig[b] @ np.linalg.inv(res.T_cam_rig[a])
        rot = float(rotation_angle_deg(T[:3, :3]))
        pu = u.pairs.get((a, b)) if u is not None else None
        sig = (f"{pu.translation_sigma_m * 1000:.3f}", f"{pu.rotation_sigma_deg:.4f}") if pu else ("-", "-")
        base = f"{1000 * np.linalg.norm(T[:3, 3]):.2f}" + (f" &plusmn; {pu.baseline_sigma_m * 1000:.3f}" if pu else "")
        h = cv.pairs.get((a, b)) if cv else None
        halves = (
            f"{h['translation_m'] * 1000:.3f} / {h['rotation_deg']:.4f} ({h['predicted_translation_sigma_m'] * 1000:.3f} / "
            f"{h['predicted_rotation_sigma_deg']:.4f})"
            if h
            else "-"
        )
        parts.append(
            f"<tr><td>{e(seq.cameras[a].name)} - {e(seq.cameras[b].name)}</td><td>{base}</td><td>{rot:.3f}</td><td>{sig[0]}</td>"
            f"<td>{sig[1]}</td><td>{halves}</td><td>{n}</td></tr>"
        )
    parts.append(
        "</table><p>Sigma: one standard deviation from the covariance of the final solve (translation and rotation as the RMS "
        "length of the error vector). Halves: the difference between calibrations from two random halves of the views, "
        "against the sigma of that difference.</p>"
    )
    return parts


def _dropped_section(res) -> list[str]:
    e = html.escape
    parts = [f"<h2>Dropped views ({len(res.dropped)})</h2>"]
    if res.dropped:
        parts.append("<table><tr><th>view</th><th>frame</th><th>cameras</th><th>reason</th></tr>")
        for d in res.dropped:
            parts.append(
                f"<tr><td>{d['view']}</td><td>{e(str(d['frame']))}</td><td>{e(', '.join(d['cameras']))}</td><td>{e(d['reason'])}</td></tr>"
            )
        parts.append("</table>")
    return parts
