"""The base install (``pip install cotrain``, no ``[train]`` extra): detection runs without torch,
a command that needs the extra says which install it needs in one line, and progress in a log is
one line per stage.

The base install is simulated in a fresh interpreter whose imports of the extra's packages fail
as they do where they are not installed (``ModuleNotFoundError``)."""

import subprocess

from cotrain.progress import progress_bar
from tests.blocked_imports import TRAIN_EXTRA, run_without
from tests.paths import ROOT, SHARED, TINY


def without_extra(entry: str, argv: list[str], cwd) -> subprocess.CompletedProcess:
    """Run ``entry``'s ``run(argv)`` (``cotrain.cli`` or ``calib_eval.cli``) without the extra."""
    return run_without(TRAIN_EXTRA, entry, argv, cwd)


def test_a_training_command_names_the_install(tmp_path):
    r = without_extra("cotrain.cli", ["train", "--config", str(TINY)], ROOT)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [
        "cotrain train: error: this command needs torch, which comes with the training extra: pip install 'cotrain[train]'"
    ]


def test_detection_runs_without_torch(tmp_path):
    images = sorted((SHARED / "real" / "ros_fisheye_stereo" / "images").glob("left-000[0-2].png"))
    board = tmp_path / "board.yaml"
    board.write_text("target_type: checkerboard\ntargetCols: 8\ntargetRows: 6\nrowSpacingMeters: 0.1\ncolSpacingMeters: 0.1\n")
    out = tmp_path / "det.json"
    r = without_extra("cotrain.cli", ["detect", *map(str, images), "--target", str(board), "--out", str(out), "--workers", "1"], ROOT)
    assert r.returncode == 0, r.stderr
    assert "3 images, " in r.stdout and out.is_file()


def test_progress_in_a_log_is_one_line_per_stage(capsys):
    for _ in progress_bar(range(5), desc="detect", unit="img"):
        pass
    bar = progress_bar(total=3, desc="train", unit="step")
    bar.update(3)
    bar.set_postfix(loss="0.5")
    bar.close()
    bar.close()  # once only
    err = capsys.readouterr().err
    assert "\r" not in err
    lines = err.splitlines()
    assert len(lines) == 2
    assert lines[0].startswith("detect: 5 img in ") and lines[1].startswith("train: 3 step in ") and lines[1].endswith("loss 0.5")
    for _ in progress_bar(range(5), desc="quiet", enabled=False):
        pass
    assert capsys.readouterr().err == ""


def test_calibrate_image_folders_without_torch_or_fov(tmp_path):
    """The issue's case: the real stereo head split into left/ and right/, no --fov, no torch."""
    import shutil

    for side in ("left", "right"):
        (tmp_path / side).mkdir()
        for f in sorted((SHARED / "real" / "ros_fisheye_stereo" / "images").glob(f"{side}-000*.png")):
            shutil.copyfile(f, tmp_path / side / f.name)
    board = tmp_path / "board.yaml"
    board.write_text("target_type: checkerboard\ntargetCols: 8\ntargetRows: 6\nrowSpacingMeters: 0.1\ncolSpacingMeters: 0.1\n")
    out = tmp_path / "calib"
    argv = ["calibrate", "--images", "left", "right", "--target", str(board), "--models", "pinhole-equi", "pinhole-equi", "--out", str(out)]
    r = without_extra("calib_eval.cli", argv, tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    lines = r.stdout.strip().splitlines()
    assert any(x.startswith("no --fov given: estimated ") for x in lines) and lines[-1].startswith("verdict: ")
    assert (out / "camchain.yaml").is_file() and (out / "report.html").is_file()
