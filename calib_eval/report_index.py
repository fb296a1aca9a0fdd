"""``report/index.html``: the main job's report on one page, for a person to read.

Self-contained (every image embedded as a data URI; no script, no external file), it shows the
stages with their result and time, the detection tables of our learned detector against the
peers per FoV with the detection plots and a few overlays (downscaled JPEG), the training curve
read from the run's tensorboard event files, and the calibration: its own ``report.html``
(:mod:`calib_eval.calibration.report_html`, verdict first) inlined with its styles scoped to its
section, then the errors against the ground truth as a small table. Nothing is shown as raw JSON.
:func:`ground_truth_rows` and :func:`markdown_table` give ``summary.md`` the same table.
"""

from __future__ import annotations

import base64
import html
import io
import math
import re
from pathlib import Path

import numpy as np

from calib_eval.detection.evaluation import EXPERIMENTAL, PAPER

CALIB_SCOPE = "calib"  # class of the section the calibration's page is inlined in
STYLE = (
    "body{font-family:sans-serif;margin:2em;max-width:80em}table{border-collapse:collapse;margin:.5em 0}"
    "td,th{border:1px solid #ccc;padding:.3em .6em;text-align:right}th{background:#f4f4f4}td.l,th.l{text-align:left}"
    "tr.ours td{font-weight:bold}img{max-width:100%}.row{display:flex;flex-wrap:wrap;gap:1em;align-items:flex-start}"
    "figure{margin:0}figcaption{font-size:.85em;color:#555}.note{color:#8a5a00}nav a{margin-right:1em}"
    f"section.{CALIB_SCOPE}{{border-left:4px solid #ddd;padding-left:1em}}"
)


def data_uri(data: bytes, mime: str) -> str:
    """``data:`` URI of ``data`` (base64)."""
    return f"data:{mime};base64,{base64.b64encode(data).decode()}"


def image_tag(path: str | Path, alt: str, max_side: int | None = None, quality: int = 80) -> str:
    """``<img>`` of the image file ``path``, embedded: as is (PNG) where ``max_side`` is None, else
    downscaled so its longer side is at most ``max_side`` and encoded as JPEG. A note where the file
    cannot be read."""
    import cv2

    path = Path(path)
    if max_side is None and path.suffix.lower() == ".png" and path.is_file():
        return f'<img alt="{html.escape(alt)}" src="{data_uri(path.read_bytes(), "image/png")}">'
    img = cv2.imread(str(path), cv2.IMREAD_COLOR) if path.is_file() else None
    if img is None:
        return f"<p class='note'>{html.escape(path.name)}: image not found or unreadable.</p>"
    s = min(1.0, (max_side or max(img.shape[:2])) / max(img.shape[:2]))
    if s < 1.0:
        img = cv2.resize(img, (max(1, round(img.shape[1] * s)), max(1, round(img.shape[0] * s))), interpolation=cv2.INTER_AREA)
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, quality])
    return f'<img alt="{html.escape(alt)}" src="{data_uri(buf.tobytes(), "image/jpeg")}">'


def figure_tag(fig, alt: str) -> str:
    """``<img>`` of a matplotlib figure as an embedded PNG (dpi 80, as report_html does)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80, bbox_inches="tight")
    return f'<img alt="{html.escape(alt)}" src="{data_uri(buf.getvalue(), "image/png")}">'


def html_table(header: list[str], rows: list[list[object]], row_class: list[str] | None = None, left: int = 1) -> str:
    """An HTML table; every cell escaped (``str`` of it). The first ``left`` columns are
    left-aligned; ``row_class``: a class per row ("" for none)."""
    e = html.escape

    def cells(tag: str, vals: list[object]) -> str:
        return "".join(f"<{tag}{' class=l' if i < left else ''}>{e(str(v))}</{tag}>" for i, v in enumerate(vals))

    parts = ["<table>", f"<tr>{cells('th', header)}</tr>"]
    for i, r in enumerate(rows):
        cls = row_class[i] if row_class and row_class[i] else ""
        parts.append(f"<tr{f' class={e(cls)}' if cls else ''}>{cells('td', r)}</tr>")
    parts.append("</table>")
    return "".join(parts)


def _num(v: object, fmt: str = ".3f") -> str:
    """A figure formatted, "-" where missing or not finite."""
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return "-"
    return format(v, fmt) if isinstance(v, (int, float)) and not isinstance(v, bool) else str(v)


def stage_table(status: dict[str, str], seconds: dict[str, float]) -> str:
    """The stages in order with their one-line result and run time."""
    rows = [[name, res, _num(seconds.get(name), ".1f") + ("\u00a0s" if name in seconds else "")] for name, res in status.items()]
    return html_table(["stage", "result", "time"], rows, left=2)


def fov_table(results: dict[str, dict], fovs: list[int]) -> str:
    """Per FoV and detector: recall, errors, outliers, labelled hidden and the paper's figures (the
    rows of the detection evaluation's markdown table). Our learned detector's rows have class ``ours``."""
    head = ["FoV", "detector", "recall", "mean err px", "median err px", "outliers", "labelled hidden", "paper recall / err"]
    rows, cls = [], []
    for fov in fovs:
        for name, r in results.items():
            row = r.get("per_fov", {}).get(str(fov))
            if row is None:
                continue
            paper = PAPER.get(fov, {}).get("learned" if name.startswith("learned") else "geometry")
            ptxt = f"{paper[0]:.3f} / {paper[1]:.3f}" if paper and name in ("learned", "opencv_sb") else ""
            rows.append([fov, name, *_error_cells(row), ptxt])
            cls.append("ours" if name == "learned" else "")
    return html_table(head, rows, cls, left=2)


def detection_tables(results: dict[str, dict], fovs: list[int]) -> str:
    """The detection evaluation's tables (the data of its ``results.md``) in HTML: per FoV
    (:func:`fov_table`), per condition where there are any, per detector the false reports on
    images without a target and the time per image; the network's experimental per-slot read-out
    apart, below, as the evaluation reports it."""
    found = {k: v for k, v in results.items() if k not in EXPERIMENTAL}
    slots = {k: v for k, v in results.items() if k in EXPERIMENTAL}
    parts = ["<h3>Per FoV</h3>", fov_table(found, fovs)]
    cond = [(c, n, row) for n, r in found.items() for c, row in r.get("per_condition", {}).items()]
    if cond:
        rows = [[c, n, *_error_cells(row)] for c, n, row in sorted(cond, key=lambda t: t[0])]
        head = ["condition", "detector", "recall", "mean err px", "median err px", "outliers", "labelled hidden"]
        parts += ["<h3>Per condition</h3>", html_table(head, rows, left=2)]
    rows = [[n, f"{r.get('false_images', 0)} / {r.get('n_empty', 0)}", _num(r.get("ms_per_image"), ".1f")] for n, r in found.items()]
    parts += ["<h3>Per detector</h3>", html_table(["detector", "images without target with reports", "ms / image (median)"], rows)]
    if slots:
        parts += [
            "<h3>Experimental: the network's per-slot read-out</h3>",
            "<p>One heatmap channel per corner id, read out by the network itself; not a detector to use.</p>",
            fov_table(slots, fovs),
        ]
    return "\n".join(parts)


def _error_cells(row: dict) -> list[str]:
    """Recall, mean and median error, outlier rate and labelled-hidden count of a table row."""
    out = row.get("outlier_rate")
    return [
        _num(row.get("recall")),
        _num(row.get("mean_error_px")),
        _num(row.get("median_error_px")),
        f"{100 * out:.2f}%" if isinstance(out, (int, float)) else "-",
        _num(row.get("n_hidden", 0), "d"),
    ]


GT_LABELS = {  # key of evaluate_result -> (label, format, unit)
    "success": ("calibration succeeded", "", ""),
    "strict": ("strict success (near the truth)", "", ""),
    "reason": ("reason", "", ""),
    "intr_px": ("intrinsics: projection difference from truth (RMS)", ".3f", "px"),
    "ext_mm": ("extrinsics: translation error (mean)", ".3f", "mm"),
    "ext_deg": ("extrinsics: rotation error (mean)", ".4f", "deg"),
    "ate_mm": ("target poses: translation error (mean)", ".3f", "mm"),
    "ate_deg": ("target poses: rotation error (mean)", ".4f", "deg"),
    "rms_px": ("reprojection RMS per camera", ".3f", "px"),
    "runtime_s": ("calibration run time", ".1f", "s"),
}


def ground_truth_rows(ev: dict) -> list[tuple[str, str]]:
    """The calibration's errors against the ground truth (``evaluate_result``) as (label, value)
    rows in a fixed order; lists are joined, unknown keys follow under their own name and the
    per-step conditioning ``gamma`` is left out (it is plotted in the calibration's page)."""
    rows = []
    for key in [*GT_LABELS, *sorted(k for k in ev if k not in GT_LABELS and k != "gamma")]:
        if key not in ev:
            continue
        label, fmt, unit = GT_LABELS.get(key, (key, ".4g", ""))
        v = ev[key]
        if isinstance(v, bool):
            txt = "yes" if v else "no"
        elif isinstance(v, (list, tuple, np.ndarray)):
            txt = ", ".join(_num(float(x), fmt or ".4g") for x in v)
        elif isinstance(v, (int, float, np.floating, np.integer)):
            txt = _num(float(v), fmt or ".4g")
        else:
            txt = str(v)
        rows.append((label, f"{txt} {unit}".strip() if txt != "-" else txt))
    return rows


def markdown_table(header: list[str], rows: list[tuple[str, ...]] | list[list[str]]) -> str:
    """A markdown table (for ``summary.md``); ``|`` in cells escaped, newlines made spaces."""

    def cell(v: object) -> str:
        return str(v).replace("|", "\\|").replace("\n", " ")

    lines = ["| " + " | ".join(cell(h) for h in header) + " |", "|" + "---|" * len(header)]
    lines += ["| " + " | ".join(cell(v) for v in r) + " |" for r in rows]
    return "\n".join(lines)


def read_training_curve(tb_dir: str | Path, tags: tuple[str, ...] = ("loss/total", "val/recall")) -> dict[str, list[tuple[int, float]]]:
    """Per tag the (step, value) pairs the training run logged to its tensorboard event files in
    ``tb_dir`` (every event file there, in step order; the last value where a step was logged
    twice, as after a resume). Tags not logged, a missing folder or no tensorboard: empty lists."""
    out: dict[str, list[tuple[int, float]]] = {t: [] for t in tags}
    tb_dir = Path(tb_dir)
    if not tb_dir.is_dir():
        return out
    try:
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    except ImportError:
        return out
    for f in sorted(tb_dir.glob("events.out.tfevents.*")):
        acc = EventAccumulator(str(f), size_guidance={"scalars": 0, "images": 1, "tensors": 1})
        acc.Reload()
        have = set(acc.Tags().get("scalars", []))
        for t in tags:
            if t in have:
                out[t] += [(int(s.step), float(s.value)) for s in acc.Scalars(t)]
    return {t: sorted(dict(v).items()) for t, v in out.items()}


def training_curve_tag(curves: dict[str, list[tuple[int, float]]]) -> str:
    """The training curve as an embedded plot: the total loss against step (log scale where it
    spans over a factor 20), and beside it the validation recall where logged; a note where nothing was logged."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    loss, recall = curves.get("loss/total", []), curves.get("val/recall", [])
    if not loss and not recall:
        return "<p class='note'>No training curve: the run logged no loss (no tensorboard event files found).</p>"
    fig, axes = plt.subplots(1, 2 if recall else 1, figsize=(10 if recall else 5.5, 3.4), squeeze=False, sharex=True)
    ax = axes[0][0]
    if loss:
        s, v = zip(*loss)
        ax.plot(s, v, marker="o" if len(s) < 30 else None, ms=3, color="tab:blue")
        if min(v) > 0 and max(v) > 20 * min(v):
            ax.set_yscale("log")
    ax.set_xlabel("step")
    ax.set_ylabel("total loss")
    ax.set_title("training loss")
    ax.grid(alpha=0.3)
    if recall:
        ax = axes[0][1]
        s, v = zip(*recall)
        ax.plot(s, v, marker="o", color="tab:green")
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("step")
        ax.set_ylabel("recall")
        ax.set_title("validation recall")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    tag = figure_tag(fig, "training curve")
    plt.close(fig)
    return tag


_BODY_PREFIX = re.compile(r"^(html|body)\s+")


def scope_css(css: str, scope: str) -> str:
    """The style sheet ``css`` (plain rules, as report_html writes) restricted to elements inside
    ``scope`` (a selector): ``body`` becomes the scope itself, every other selector is prefixed
    with it. At-rules (``@media`` and the like) are dropped: they would not nest correctly."""
    out = []
    for rule in css.split("}"):
        if "{" not in rule:
            continue
        sel, decl = rule.split("{", 1)
        if sel.strip().startswith("@") or "{" in decl:
            continue
        scoped = []
        for s in (s.strip() for s in sel.split(",")):
            if s in ("body", "html"):
                scoped.append(scope)
            elif s:
                scoped.append(f"{scope} {_BODY_PREFIX.sub('', s)}")
        if scoped:
            out.append(f"{','.join(scoped)}{{{decl.strip()}}}")
    return "".join(out)


def inline_page(page: str, scope: str, demote: int = 2) -> tuple[str, str]:
    """A whole HTML page made fit to sit in a section of another: (the content of its ``<body>``
    with headings demoted by ``demote`` levels (at most h6), its ``<style>`` sheets scoped to
    ``scope`` by :func:`scope_css`). Scripts are removed."""
    styles = re.findall(r"<style[^>]*>(.*?)</style>", page, flags=re.S | re.I)
    m = re.search(r"<body[^>]*>(.*)</body>", page, flags=re.S | re.I)
    body = m.group(1) if m else re.sub(r"<head.*?</head>|</?html[^>]*>|<!doctype[^>]*>", "", page, flags=re.S | re.I)
    body = re.sub(r"<script.*?</script>", "", body, flags=re.S | re.I)
    body = re.sub(r"<(/?)h([1-6])\b", lambda h: f"<{h.group(1)}h{min(6, int(h.group(2)) + demote)}", body, flags=re.I)
    return body.strip(), "".join(scope_css(s, scope) for s in styles)


def calibration_section(page: str | None, gt_rows: list[tuple[str, str]], status: str = "") -> tuple[str, str]:
    """The calibration section: the errors against the ground truth, then the calibration's own
    page (``report.html``, verdict first) inlined, or, where there is none, a note and the one-line
    ``status`` of the calibration stage. Returns (html, css)."""
    parts = ["<h2 id='calibration'>Calibration</h2>"]
    parts.append("<h3>Against the ground truth</h3>")
    parts.append(html_table(["figure", "value"], [list(r) for r in gt_rows]) if gt_rows else "<p class='note'>No comparison.</p>")
    if page is None:
        parts.append("<p class='note'>The calibration's own page (calibration/report.html) was not written.</p>")
        if status:
            parts.append(f"<p>{html.escape(status)}</p>")
        return "\n".join(parts), ""
    body, css = inline_page(page, f"section.{CALIB_SCOPE}")
    parts += ["<h3>The calibration's own report</h3>", f"<section class='{CALIB_SCOPE}'>", body, "</section>"]
    return "\n".join(parts), css


def gallery(tags: list[tuple[str, str]]) -> str:
    """A row of figures: (``<img>`` tag, caption) pairs; captions escaped."""
    figs = [f"<figure>{t}<figcaption>{html.escape(c)}</figcaption></figure>" for t, c in tags]
    return "<div class='row'>" + "".join(figs) + "</div>"


def build_page(
    title: str,
    intro: str,
    stages: str,
    detection: str,
    detection_figs: list[tuple[str, str]],
    overlay_figs: list[tuple[str, str]],
    curve: str,
    calibration: tuple[str, str],
) -> str:
    """The whole page from its parts (HTML fragments; ``intro`` is plain text, escaped): the
    stages, detection (tables, plots, overlays), training curve and calibration (html, its scoped
    css), with links to the sections at the top."""
    e = html.escape
    cal_html, cal_css = calibration
    sections = [("stages", "Stages"), ("detection", "Detection"), ("training", "Training"), ("calibration", "Calibration")]
    parts = [
        f"<!doctype html><html><head><meta charset='utf-8'><title>{e(title)}</title>",
        f"<style>{STYLE}{cal_css}section.{CALIB_SCOPE}{{margin:1em 0;max-width:none}}"
        f"section.{CALIB_SCOPE} h3{{font-size:1.4em}}section.{CALIB_SCOPE} h4{{font-size:1.15em}}"
        f"section.{CALIB_SCOPE} h5{{font-size:1em}}</style></head><body>",
        f"<h1>{e(title)}</h1>",
        "<nav>" + "".join(f"<a href='#{a}'>{e(t)}</a>" for a, t in sections) + "</nav>",
        f"<p>{e(intro)}</p>",
        "<h2 id='stages'>Stages</h2>",
        stages,
        "<h2 id='detection'>Detection per FoV: the learned detector against the peers</h2>",
        detection,
        gallery(detection_figs) if detection_figs else "<p class='note'>No detection plots.</p>",
        "<h3>Detections drawn on evaluation images</h3>",
        gallery(overlay_figs) if overlay_figs else "<p class='note'>No overlays.</p>",
        "<h2 id='training'>Training</h2>",
        curve,
        cal_html,
        "</body></html>",
    ]
    return "\n".join(parts)


def write_index(
    out_dir: str | Path,
    status: dict[str, str],
    seconds: dict[str, float],
    detection_results: dict[str, dict],
    fovs: list[int],
    ground_truth: dict,
    total_s: float,
    overlay_side: int = 480,
) -> Path:
    """Write ``out_dir/index.html`` from the report folder the main job filled (detection/*.png,
    overlays/*.png, train/tb, calibration/report.html; any of them may be missing) and the figures
    given; returns its path."""
    out = Path(out_dir)
    plots = sorted((out / "detection").glob("*.png"), key=lambda p: (p.stem != "recall_vs_radius", p.name))  # recall first
    det_figs = [(image_tag(p, p.stem), p.stem.replace("_", " ")) for p in plots]
    ov_figs = [(image_tag(p, p.stem, max_side=overlay_side), p.name) for p in sorted((out / "overlays").glob("*.png"))]
    page_path = out / "calibration" / "report.html"
    page = page_path.read_text() if page_path.is_file() else None
    page_html = build_page(
        "cotrain pipeline report",
        f"Total time {total_s / 60:.1f} min. Report folder: {out}.",
        stage_table(status, seconds),
        detection_tables(detection_results, fovs),
        det_figs,
        ov_figs,
        training_curve_tag(read_training_curve(out / "train" / "tb")),
        calibration_section(page, ground_truth_rows(ground_truth), status.get("calibration", "")),
    )
    path = out / "index.html"
    path.write_text(page_html)
    return path
