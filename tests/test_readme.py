"""The README's quick starts, run as written: each ```bash block under a "Quick start" heading is
run line by line in a folder that holds what the quick start assumes (a bag or image folders of
the real stereo head in ../shared, the Kalibr target yaml of its board, the repository's
configs/), and its outputs are checked. So the README cannot drift from the code."""

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from tests.paths import ROOT, SHARED

README = ROOT / "README.md"
STEREO = SHARED / "real" / "ros_fisheye_stereo" / "images"
PAIRS = 16  # of the head's 46, to keep the test short
BOARD = "target_type: checkerboard\ntargetCols: 8\ntargetRows: 6\nrowSpacingMeters: 0.1\ncolSpacingMeters: 0.1\n"


def quick_starts() -> dict[str, list[str]]:
    """{heading: the commands of its ```bash blocks} for every "## Quick start: ..." section."""
    out = {}
    for section in re.split(r"^## ", README.read_text(), flags=re.M)[1:]:
        title, _, body = section.partition("\n")
        if title.startswith("Quick start"):
            blocks = re.findall(r"```bash\n(.*?)```", body, flags=re.S)
            out[title] = [ln for b in blocks for ln in b.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    return out


def run_block(commands: list[str], cwd: Path) -> str:
    """Run the commands in turn (stop at the first failure); returns the output of the last."""
    env = {**os.environ, "PATH": f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}"}
    out = ""
    for cmd in commands:
        r = subprocess.run(cmd, shell=True, cwd=cwd, env=env, capture_output=True, text=True, timeout=1200)
        assert r.returncode == 0, f"{cmd!r} failed ({r.returncode}):\n{r.stdout[-2000:]}\n{r.stderr[-2000:]}"
        out = r.stdout
    return out


def stereo_pairs():
    if not STEREO.is_dir():
        pytest.skip(f"{STEREO} is not beside the clone")
    return [(STEREO / f"left-{k:04d}.png", STEREO / f"right-{k:04d}.png") for k in range(PAIRS)]


def test_readme_is_short_and_has_the_three_quick_starts():
    assert len(README.read_text().splitlines()) <= 150
    titles = list(quick_starts())
    assert len(titles) == 3 and any("bag" in t for t in titles) and any("folders" in t for t in titles)
    assert any("train" in t for t in titles)


def test_quick_start_bag(tmp_path):
    from cotrain.io.bags import write_image_bag

    pairs = stereo_pairs()
    (tmp_path / "checkerboard.yaml").write_text(BOARD)
    t0 = 1_700_000_000_000_000_000
    cams = [[(t0 + k * 10**9, cv2.imread(str(p[c]), cv2.IMREAD_GRAYSCALE)) for k, p in enumerate(pairs)] for c in range(2)]
    write_image_bag(tmp_path / "stereo.bag", 1, cams)
    (cmds,) = [c for t, c in quick_starts().items() if "bag" in t]
    last = run_block(cmds, tmp_path).strip().splitlines()[-1]
    assert last.startswith("verdict: ")
    for f in ("camchain.yaml", "report.html", "report.json"):
        assert (tmp_path / "calib" / f).is_file()
    assert "cam1:" in (tmp_path / "calib" / "camchain.yaml").read_text()
    assert (tmp_path / "calib" / "sequence" / "cam1" / "detections.json").is_file()


def test_quick_start_image_folders(tmp_path):
    pairs = stereo_pairs()
    (tmp_path / "checkerboard.yaml").write_text(BOARD)
    for c, side in enumerate(("left", "right")):
        (tmp_path / side).mkdir()
        for p in pairs:
            shutil.copyfile(p[c], tmp_path / side / p[c].name)
    (cmds,) = [c for t, c in quick_starts().items() if "folders" in t]
    run_block(cmds, tmp_path)
    assert (tmp_path / "calib" / "camchain.yaml").is_file() and (tmp_path / "calib" / "report.html").is_file()
    log = (tmp_path / "calib" / "report.json").read_text()
    assert '"success": true' in log
    assert len(list((tmp_path / "overlays").glob("*.png"))) == PAIRS and (tmp_path / "left.json").is_file()


def test_quick_start_train_export_evaluate(tmp_path):
    (tmp_path / "configs").symlink_to(ROOT / "configs", target_is_directory=True)
    (cmds,) = [c for t, c in quick_starts().items() if "train" in t]
    run_block(cmds, tmp_path)
    assert (tmp_path / "preview.png").is_file() and (tmp_path / "quick.onnx").is_file()
    results = (tmp_path / "eval" / "results.md").read_text()
    assert "learned" in results and "200" in results
