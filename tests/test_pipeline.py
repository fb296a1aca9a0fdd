"""The main job end to end on a tiny setting, and its early, one-line failures."""

import json

import torch

from cotrain.cli import run as cotrain_cli
from tests.paths import ROOT, TINY


def test_pipeline_tiny_end_to_end(tmp_path):
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
    assert "| calibration | strict success" in (out / "summary.md").read_text()


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
