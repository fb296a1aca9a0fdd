"""`calib-eval detection` on frames of another size than 1280x720 (another rig)."""

import json

import cv2

from calib_eval.cli import run as calib_cli


def test_detection_eval_renders_and_scores_another_image_size(tmp_path):
    out = tmp_path / "det"
    args = ["detection", "--size", "480x400", "--seed", "5", "--fov", "200", "--per-fov", "2", "--empty", "1"]
    args += ["--per-condition", "1", "--conditions", "over-exposed"]
    assert calib_cli([*args, "--detectors", "learned", "learned_slots", "--out", str(out)]) == 0
    labels = json.loads((out / "labels.json").read_text())
    assert labels["config"]["width"] == 480 and labels["config"]["height"] == 400 and labels["config"]["seed"] == 5
    for lab in labels["labels"]:
        assert cv2.imread(str(out / "images" / lab["image"]), cv2.IMREAD_UNCHANGED).shape == (400, 480)
    assert "| 200 | learned |" in (out / "results.md").read_text()
    md = (out / "results.md").read_text()
    assert "| over-exposed | learned |" in md
    # The per-slot read-out is reported apart, as the network's experimental output, not as a detector.
    assert md.index("| 200 | learned |") < md.index("## Experimental") < md.index("| 200 | learned_slots |")
    (cond,) = [lab for lab in labels["labels"] if lab["condition"]]
    assert cond["condition"] == "over-exposed" and 180 <= cond["fov"] <= 240 and cond["image"].startswith("over_exposed")


def test_detection_eval_refuses_a_bad_size(tmp_path, capsys):
    assert calib_cli(["detection", "--size", "480by400", "--out", str(tmp_path / "d")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--size" in err[0]


def test_a_set_is_reused_for_its_config_and_rendered_again_for_another(tmp_path):
    from calib_eval.detection.evaluation import EvalConfig, load_or_render

    cfg = EvalConfig(fovs=[200], per_fov=1, n_empty=0, seed=3, width=160, height=120, conditions=[])
    meta = load_or_render(cfg, tmp_path, progress=False)
    img = tmp_path / "images" / meta["labels"][0]["image"]
    (tmp_path / "predictions_learned.json").write_text("{}")
    stamp = img.stat().st_mtime_ns
    assert load_or_render(cfg, tmp_path, progress=False) == meta  # same config: reused as is
    assert img.stat().st_mtime_ns == stamp and (tmp_path / "predictions_learned.json").is_file()
    other = load_or_render(
        EvalConfig(fovs=[200], per_fov=1, n_empty=0, seed=4, width=160, height=120, conditions=[]), tmp_path, progress=False
    )
    assert other["config"]["seed"] == 4
    assert not (tmp_path / "predictions_learned.json").exists()  # predictions of the old set are gone
