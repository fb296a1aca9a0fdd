"""report/index.html's parts (calib_eval.report_index) on small hand-made inputs."""

import base64
import re

import cv2
import numpy as np

from calib_eval.report_index import (
    build_page,
    calibration_section,
    detection_tables,
    ground_truth_rows,
    html_table,
    image_tag,
    inline_page,
    markdown_table,
    read_training_curve,
    scope_css,
    stage_table,
    training_curve_tag,
    write_index,
)


def assert_self_contained(page: str) -> None:
    """Every src/href is a data: URI or an in-page anchor; no script, no linked style sheet, no
    CSS url() to a file, no raw JSON object."""
    refs = re.findall(r"""\b(?:src|href)\s*=\s*["']?([^"'\s>]*)""", page, flags=re.I)
    bad = [r[:60] for r in refs if not (r.startswith("data:") or r.startswith("#"))]
    assert not bad, bad
    assert not re.search(r"<script|<link|<iframe[^>]*\bsrc=|url\((?!data:)", page, flags=re.I)
    assert not re.search(r"""\{\s*["']\w+["']\s*:""", page) and "```" not in page


def _row(recall, err):
    return {"recall": recall, "mean_error_px": err, "median_error_px": err, "outlier_rate": 0.01, "n_hidden": 2}


RESULTS = {
    "learned": {"per_fov": {"200": _row(0.95, 0.5), "240": _row(0.9, 0.6)}, "false_images": 0, "n_empty": 2, "ms_per_image": 40.0},
    "<b>peer</b>": {"per_fov": {"200": _row(0.7, float("nan"))}, "false_images": 1, "n_empty": 2, "ms_per_image": 300.0},
    "learned_slots": {"per_fov": {"200": _row(0.1, 2.0)}, "false_images": 0, "n_empty": 2, "ms_per_image": 10.0},
}


def test_html_table_escapes_every_cell():
    t = html_table(["a<b", "c"], [["<script>x</script>", "R&D"]], ["ours"])
    assert "<script>" not in t and "&lt;script&gt;x&lt;/script&gt;" in t and "R&amp;D" in t and "a&lt;b" in t
    assert t.count("<tr") == 2 and "<tr class=ours>" in t


def test_detection_tables_rows_per_fov_and_detector():
    t = detection_tables(RESULTS, [200, 240])
    # Our learned detector's rows, marked, with the paper's figures for that FoV; a peer's name escaped.
    assert "<tr class=ours><td class=l>200</td><td class=l>learned</td><td>0.950</td><td>0.500</td>" in t
    assert "<td class=l>240</td><td class=l>learned</td><td>0.900</td>" in t and "0.934 / 0.794" in t
    assert "&lt;b&gt;peer&lt;/b&gt;" in t and "<b>peer</b>" not in t
    assert "<td>0.700</td><td>-</td>" in t  # a NaN error is shown as "-"
    assert "<td>1.00%</td>" in t and "1 / 2" in t and "300.0" in t
    # The experimental per-slot read-out comes after the detectors, in a table of its own.
    main, _, experimental = t.partition("Experimental")
    assert "learned_slots" not in main and "<td class=l>learned_slots</td><td>0.100</td>" in experimental


def test_stage_table_has_result_and_time():
    t = stage_table({"train": "ok", "calibration": "strict success; verdict: trust"}, {"train": 12.34})
    assert "<td class=l>train</td><td class=l>ok</td><td>12.3\u00a0s</td>" in t
    assert "<td class=l>calibration</td><td class=l>strict success; verdict: trust</td><td>-</td>" in t


def test_ground_truth_rows_and_markdown_table():
    ev = {"success": True, "reason": "ok", "runtime_s": 1.25, "gamma": [[1.0, 2.0]], "intr_px": 0.0712, "rms_px": [0.05, 0.061]}
    ev.update({"ext_mm": 0.05, "ext_deg": 0.006, "strict": False, "extra|key": 3})
    rows = dict(ground_truth_rows(ev))
    assert rows["calibration succeeded"] == "yes" and rows["strict success (near the truth)"] == "no"
    assert rows["intrinsics: projection difference from truth (RMS)"] == "0.071 px"
    assert rows["reprojection RMS per camera"] == "0.050, 0.061 px" and rows["extra|key"] == "3"
    assert not any("gamma" in k for k in rows)
    md = markdown_table(["figure", "value"], ground_truth_rows(ev))
    lines = md.splitlines()
    assert lines[0] == "| figure | value |" and lines[1] == "|---|---|" and "| extra\\|key | 3 |" in lines
    assert "{" not in md and len(lines) == 2 + len(rows)


def test_read_training_curve_returns_logged_steps(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    w = SummaryWriter(str(tmp_path / "tb"))
    for step, loss in [(1, 3.0), (2, 2.5), (5, 1.0)]:
        w.add_scalar("loss/total", loss, step)
        w.add_scalar("loss/heatmap", loss / 2, step)
    w.add_scalar("val/recall", 0.25, 5)
    w.close()
    c = read_training_curve(tmp_path / "tb")
    assert [s for s, _ in c["loss/total"]] == [1, 2, 5] and np.allclose([v for _, v in c["loss/total"]], [3.0, 2.5, 1.0])
    assert c["val/recall"] == [(5, 0.25)]
    assert read_training_curve(tmp_path / "missing") == {"loss/total": [], "val/recall": []}
    assert read_training_curve(tmp_path / "tb", tags=("val/error_px",)) == {"val/error_px": []}


def test_training_curve_tag_is_an_embedded_png_or_a_note():
    tag = training_curve_tag({"loss/total": [(1, 3.0), (2, 2.0)], "val/recall": [(2, 0.5)]})
    m = re.fullmatch(r'<img alt="training curve" src="data:image/png;base64,([A-Za-z0-9+/=]+)">', tag)
    assert m and base64.b64decode(m.group(1))[:8] == b"\x89PNG\r\n\x1a\n"
    assert "<img" not in training_curve_tag({"loss/total": [], "val/recall": []}) and "No training curve" in training_curve_tag({})


def test_image_tag_embeds_png_and_downscales_to_jpeg(tmp_path):
    p = tmp_path / "a.png"
    cv2.imwrite(str(p), np.full((500, 1000, 3), 128, np.uint8))
    assert image_tag(p, "x").startswith('<img alt="x" src="data:image/png;base64,')
    tag = image_tag(p, "a<b", max_side=100)
    assert 'alt="a&lt;b"' in tag
    data = base64.b64decode(tag.split("base64,")[1].rstrip('">'))
    assert data[:2] == b"\xff\xd8"  # JPEG
    assert cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR).shape == (50, 100, 3)
    assert "<img" not in image_tag(tmp_path / "missing.png", "m") and "missing.png" in image_tag(tmp_path / "missing.png", "m")


def test_scope_css_and_inline_page():
    css = scope_css("body{margin:2em}table,td>b{border:0}@media print{td{color:red}}body .row{gap:1em}", "section.c")
    assert css == "section.c{margin:2em}section.c table,section.c td>b{border:0}section.c .row{gap:1em}"
    page = (
        "<!doctype html><html><head><style>h1{color:red}</style></head><body class='x'><h1 style='color:#2e7d32'>Verdict: trust"
        "</h1><h3>cam0</h3><script>alert(1)</script><p>ok</p></body></html>"
    )
    body, scoped = inline_page(page, "section.c")
    assert body == "<h3 style='color:#2e7d32'>Verdict: trust</h3><h5>cam0</h5><p>ok</p>"
    assert scoped == "section.c h1{color:red}"


def test_calibration_section_inlines_the_page_or_notes_its_absence():
    rows = [("calibration succeeded", "yes")]
    html_, css = calibration_section("<html><head><style>td{x:y}</style></head><body><h1>Verdict: caution</h1></body></html>", rows)
    assert "<section class='calib'>" in html_ and "<h3>Verdict: caution</h3>" in html_ and css == "section.calib td{x:y}"
    assert "<td class=l>calibration succeeded</td><td>yes</td>" in html_
    html_, css = calibration_section(None, rows, "failed: too few views; verdict: fail")
    assert "was not written" in html_ and "failed: too few views; verdict: fail" in html_ and css == ""
    assert "<section" not in html_


def test_page_without_calibration_page_or_plots_still_renders(tmp_path):
    status = {"train": "ok", "calibration": "failed: <few> views; verdict: fail"}
    path = write_index(tmp_path, status, {"train": 3.0}, RESULTS, [200, 240], {"success": False, "reason": "few views"}, 90.0)
    page = path.read_text()
    assert path == tmp_path / "index.html" and page.startswith("<!doctype html>") and page.rstrip().endswith("</html>")
    assert "was not written" in page and "failed: &lt;few&gt; views; verdict: fail" in page
    assert "No detection plots." in page and "No overlays." in page and "No training curve" in page
    assert "<td class=l>240</td><td class=l>learned</td>" in page and "Total time 1.5 min" in page
    assert_self_contained(page)


def test_build_page_assembles_sections_with_scoped_style():
    page = build_page(
        "t<1>", "intro & more", "<table>S</table>", "<table>D</table>", [("<img alt=a src='data:x'>", "a_b")], [], "C", ("CAL", ".q{}")
    )
    assert "<title>t&lt;1&gt;</title>" in page and "<p>intro &amp; more</p>" in page and ".q{}" in page
    order = [page.index(s) for s in ("id='stages'", "<table>S", "<table>D", "a_b", "No overlays.", "id='training'", "C\nCAL")]
    assert order == sorted(order)
    assert_self_contained(page)


def test_write_index_embeds_what_the_report_folder_holds(tmp_path):
    from torch.utils.tensorboard import SummaryWriter

    for name in ("error_distribution", "recall_vs_radius"):
        (tmp_path / "detection").mkdir(exist_ok=True)
        cv2.imwrite(str(tmp_path / "detection" / f"{name}.png"), np.zeros((40, 60, 3), np.uint8))
    (tmp_path / "overlays").mkdir()
    cv2.imwrite(str(tmp_path / "overlays" / "fov200_000.png"), np.full((720, 1280, 3), 200, np.uint8))
    (tmp_path / "calibration").mkdir()
    (tmp_path / "calibration" / "report.html").write_text(
        "<!doctype html><html><head><style>body{margin:2em}</style></head><body><h1>Verdict: trust</h1><p>fine</p></body></html>"
    )
    w = SummaryWriter(str(tmp_path / "train" / "tb"))
    w.add_scalar("loss/total", 1.0, 1)
    w.close()
    page = write_index(tmp_path, {"train": "ok"}, {"train": 1.0}, RESULTS, [200], {"success": True, "ext_mm": 0.5}, 60).read_text()
    assert_self_contained(page)
    # Detection plots as PNG, recall first; the overlay downscaled to JPEG; the curve; the calibration's page inlined.
    assert page.index('alt="recall_vs_radius" src="data:image/png') < page.index('alt="error_distribution" src="data:image/png')
    assert page.count('src="data:image/jpeg') == 1 and "fov200_000.png</figcaption>" in page
    assert '<img alt="training curve" src="data:image/png' in page
    assert "<section class='calib'>\n<h3>Verdict: trust</h3><p>fine</p>\n</section>" in page and "section.calib{margin:2em}" in page
    assert "<td class=l>extrinsics: translation error (mean)</td><td>0.500 mm</td>" in page
    assert "was not written" not in page and "No training curve" not in page
