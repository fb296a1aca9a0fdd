"""The main job end to end on a tiny setting, and its early, one-line failures."""

import html
import json
import re

import torch

from cotrain.cli import run as cotrain_cli
from tests.paths import ROOT, TINY
from tests.test_report_index import assert_self_contained


def test_pipeline_tiny_end_to_end(tmp_path, capsys):
    """A 2-step model, then the calibration check through it: 32 rendered stereo frames (fewer
    leave cam1 under the 4 views it needs after selection) must calibrate strictly."""
    out = tmp_path / "report"
    threads = torch.get_num_threads()
    torch.set_num_threads(1)  # rendering 1280x720 frames: threads only contend on a shared machine
    try:
        rc = _pipeline(out)
    finally:
        torch.set_num_threads(threads)
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["status"]) == {"train", "export", "detection", "calibration"}
    assert summary["status"]["train"] == "ok" and summary["status"]["export"].startswith("ok")
    assert (out / "summary.md").is_file() and (out / "model.onnx").is_file()
    assert (out / "detection" / "results.md").is_file() and (out / "detection" / "recall_vs_radius.png").is_file()
    assert (out / "calibration" / "report.json").is_file() and any((out / "overlays").iterdir())
    assert any((out / "train" / "tb").iterdir())
    # The calibration check succeeded, strictly, close to the truth (measured: 0.05 mm / 0.006 deg,
    # 0.07 px from the true projection, 0.04-0.06 px RMS on the rendered corners).
    status = summary["status"]["calibration"]
    assert status.startswith("strict success"), status
    cal = summary["figures"]["calibration"]
    assert cal["success"] and cal["reason"] == "ok" and cal["strict"], cal
    assert cal["intr_px"] < 0.5 and cal["ext_mm"] < 1.0 and cal["ext_deg"] < 0.1 and max(cal["rms_px"]) < 0.3, cal
    report = json.loads((out / "calibration" / "report.json").read_text())
    assert report["success"] and report["reason"] == "ok" and set(report["rms_px"]) == {"cam0", "cam1"}
    assert max(report["rms_px"].values()) < 0.3 and min(report["frames_per_stage"]["full"]) >= 4
    assert (out / "calibration" / "camchain.yaml").is_file()
    # It says how far to trust it: a verdict on the page and in the status line.
    assert report["verdict"]["level"] in ("trust", "caution") and "Verdict: " in (out / "calibration" / "report.html").read_text()
    assert "verdict: " in status
    md = (out / "summary.md").read_text()
    assert "| calibration | strict success" in md
    # summary.md: the figures against the truth as a small table, no raw JSON block.
    assert "```" not in md and "| strict success (near the truth) | yes |" in md and '"ext_mm"' not in md
    # The last line printed points to the one page to read.
    assert capsys.readouterr().out.strip().splitlines()[-1].endswith(str(out / "index.html"))
    _check_index(out, summary, report)


def _check_index(out, summary, report):
    """report/index.html: self-contained, the stages, the detection rows per FoV, the training
    curve, the calibration's own page (verdict first) and the figures against the truth, no JSON."""
    page = (out / "index.html").read_text()
    assert_self_contained(page)
    assert len(page.encode()) < 3_000_000
    assert set(summary["seconds"]) == set(summary["status"])
    for stage, result in summary["status"].items():
        assert f"<td class=l>{stage}</td><td class=l>{html.escape(result)}</td>" in page
    status = summary["status"]["calibration"]
    assert html.escape(status[status.index("verdict: ") :]) in page  # the verdict line
    assert f"Verdict: {report['verdict']['level']}</h3>" in page and "<section class='calib'>" in page
    for fov in (200, 240):
        assert f"<tr class=ours><td class=l>{fov}</td><td class=l>learned</td>" in page
        assert f"<td class=l>{fov}</td><td class=l>opencv_sb</td>" in page
    assert re.search(r'<img alt="training curve" src="data:image/png;base64,[A-Za-z0-9+/=]{100,}">', page)
    assert page.count('alt="recall_vs_radius" src="data:image/png') == 1 and page.count('src="data:image/jpeg') == 2
    assert "<td class=l>strict success (near the truth)</td><td>yes</td>" in page


def _pipeline(out):
    return cotrain_cli(
        [
            "pipeline",
            "--config",
            str(ROOT / "configs" / "pipeline.yaml"),
            "--from-scratch",
            f"out_dir={out}",
            f"train_config={TINY}",
            "train_steps=2",
            "eval_per_fov=2",
            "eval_empty=1",
            "eval_fovs=[200, 240]",
            "calib_frames=32",
            "overlays=2",
            "train_overrides=[]",
        ]
    )


def test_pipeline_bad_inputs_fail_early(tmp_path, capsys):
    cfg = str(ROOT / "configs" / "pipeline.yaml")
    assert cotrain_cli(["pipeline", "--config", cfg, f"out_dir={tmp_path}", f"init_checkpoint={tmp_path / 'none.pt'}"]) == 2
    assert cotrain_cli(["pipeline", "--config", cfg, "train_stepz=3"]) == 2
    assert cotrain_cli(["pipeline", "--config", str(tmp_path / "missing.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all("error:" in line for line in err)
