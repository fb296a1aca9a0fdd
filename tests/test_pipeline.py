"""The main job end to end on a tiny setting, and its early, one-line failures."""

import json

from cotrain.cli import run as cotrain_cli
from tests.paths import ROOT, TINY


def test_pipeline_tiny_end_to_end(tmp_path):
    out = tmp_path / "report"
    rc = cotrain_cli(
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
            "calib_frames=6",
            "overlays=2",
            "train_overrides=[]",
        ]
    )
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert set(summary["status"]) == {"train", "export", "detection", "calibration"}
    assert (out / "summary.md").is_file() and (out / "model.onnx").is_file()
    assert (out / "detection" / "results.md").is_file() and (out / "detection" / "recall_vs_radius.png").is_file()
    assert (out / "calibration" / "report.json").is_file() and any((out / "overlays").iterdir())
    assert any((out / "train" / "tb").iterdir())


def test_pipeline_bad_inputs_fail_early(tmp_path, capsys):
    cfg = str(ROOT / "configs" / "pipeline.yaml")
    assert cotrain_cli(["pipeline", "--config", cfg, f"out_dir={tmp_path}", f"init_checkpoint={tmp_path / 'none.pt'}"]) == 2
    assert cotrain_cli(["pipeline", "--config", cfg, "train_stepz=3"]) == 2
    assert cotrain_cli(["pipeline", "--config", str(tmp_path / "missing.yaml")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 3 and all("error:" in line for line in err)
