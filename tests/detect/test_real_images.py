"""Real, camera-captured fisheye images (../shared/real, CC-BY 4.0 BoofCV-Data, Peter Abeles)."""

import json
from pathlib import Path

import pytest
import yaml

from calib_eval.cli import run as calib_cli
from cotrain.cli import run as cotrain_cli
from cotrain.detect.detector import Detector
from cotrain.detect.images import load_image
from cotrain.targets import Checkerboard, TargetConfig
from tests.paths import SHARED

REAL = SHARED / "real" / "boofcv_fisheye_chessboard"
pytestmark = pytest.mark.skipif(not REAL.is_dir(), reason="../shared/real is not beside the checkout")


def _calibrate_ucm(seq: Path, tmp_path: Path) -> tuple[dict, dict]:
    """``calib-eval calibrate`` of a one-camera sequence of the 5 x 7 board with the UCM model:
    (report.json, camchain cam0)."""
    target = tmp_path / "target.yaml"
    target.write_text("squares_x: 5\nsquares_y: 7\nsquare_size: 1.0\nmargin: 0.0\n")
    out = tmp_path / f"out_{seq.name}"
    assert calib_cli(["calibrate", str(seq), "--fov", "190", "--model", "ucm", "--target", str(target), "--out", str(out)]) == 0
    return json.loads((out / "report.json").read_text()), yaml.safe_load((out / "camchain.yaml").read_text())["cam0"]


def test_calibrate_real_fisheye_against_boofcv(tmp_path):
    """OpenCV detections -> our sequence layout -> UCM calibration. BoofCV's own calibration of the
    same images (Mei model with radial distortion) puts the principal point at (319.18, 319.72)."""
    seq = tmp_path / "seq"
    assert calib_cli(["opencv-detect", str(REAL / "images"), "--squares-x", "5", "--squares-y", "7", "--out", str(seq)]) == 0
    det = json.loads((seq / "cam0" / "detections.json").read_text())
    assert sum(1 for e in det["images"] if len(e["corners"]) == 24) >= 24
    report, cam = _calibrate_ucm(seq, tmp_path)
    assert report["success"] and report["rms_px"]["cam0"] < 0.5
    xi, fx, fy, cx, cy = cam["intrinsics"]
    assert cam["camera_model"] == "omni" and xi > 1.0  # over 180 degrees
    assert abs(cx - 319.18) < 2.0 and abs(cy - 319.72) < 2.0


def test_detector_runs_on_real_images():
    """The shipped model on every real frame, told the board (5 x 7 squares, 24 corners): arrays of
    the documented shapes, pixels inside, and the board found with (nearly) all its corners in
    (nearly) every frame (measured: all 24 in all 26 frames)."""
    det = Detector(threads=1, target=Checkerboard(TargetConfig(squares_x=5, squares_y=7)))
    frames = sorted((REAL / "images").glob("*.jpg"))
    assert len(frames) == 26
    counts = []
    for p in frames:
        img = load_image(p)
        d = det.detect(img)
        assert d.xy.shape == (len(d.ids), 2) and (d.width, d.height) == (640, 720)
        assert ((d.xy >= -0.5) & (d.xy < [639.5, 719.5])).all()
        assert len(set(d.ids.tolist())) == len(d.ids) and ((d.ids >= 0) & (d.ids < 24)).all(), p.name
        assert ((d.confidence >= 0) & (d.confidence <= 1)).all()
        counts.append(len(d.ids))
    assert sum(c == 24 for c in counts) >= 24 and min(counts) >= 20, counts


def test_learned_detector_on_real_frames_of_another_board(tmp_path):
    """Our detector on a board it was not trained for (7 x 5 squares, symmetric under a half
    turn): the network's corner and board maps still find the squares and the grid pass places
    the lattice from the geometry alone. Every frame's corners agree with OpenCV's (up to the half
    turn), and the calibration is as good as with OpenCV's corners (0.31 px RMS)."""
    import numpy as np

    seq, ref = tmp_path / "seq", tmp_path / "ref"
    args = [str(REAL / "images"), "--squares-x", "5", "--squares-y", "7"]
    assert calib_cli(["opencv-detect", *args, "--learned", "--out", str(seq)]) == 0
    assert calib_cli(["opencv-detect", *args, "--out", str(ref)]) == 0
    ours = json.loads((seq / "cam0" / "detections.json").read_text())["images"]
    cv = json.loads((ref / "cam0" / "detections.json").read_text())["images"]
    assert sum(len(e["corners"]) == 24 for e in ours) >= 25
    for e, r in zip(ours, cv):
        if not e["corners"] or not r["corners"]:
            continue
        q = {c["id"]: (c["x"], c["y"]) for c in r["corners"]}
        d = [np.hypot(c["x"] - q[i][0], c["y"] - q[i][1]) for c in e["corners"] for i in (c["id"], 23 - c["id"])]
        d = np.array(d).reshape(-1, 2)
        d = d[:, np.argmin(np.median(d, 0))]  # OpenCV's order or its half turn
        assert np.median(d) < 0.3 and d.max() < 3.0, e["path"]
    report, cam = _calibrate_ucm(seq, tmp_path)
    assert report["success"] and report["rms_px"]["cam0"] < 0.35
    cx, cy = cam["intrinsics"][3:5]
    assert abs(cx - 319.18) < 2.0 and abs(cy - 319.72) < 2.0


def test_detect_reads_the_boofcv_target_yaml_beside_the_images(tmp_path):
    """``cotrain detect --target calibration_target.yaml``, the BoofCV file the folder comes with:
    the JSON names its 5 x 7 chessboard, and three frames give all 24 corners each, with the ids
    and positions of ``--squares-x 5 --squares-y 7`` (a board read turned would number them
    otherwise)."""
    frames = sorted((REAL / "images").glob("*.jpg"))[:3]
    out = tmp_path / "d.json"
    args = ["detect", "--target", str(REAL / "calibration_target.yaml"), *map(str, frames), "--out", str(out)]
    assert cotrain_cli(args) == 0
    d = json.loads(out.read_text())
    assert d["target"] == {"kind": "checkerboard", "squares_x": 5, "squares_y": 7, "square_size": 1.0}
    assert [len(e["corners"]) for e in d["images"]] == [24, 24, 24]
    flags = tmp_path / "f.json"
    assert cotrain_cli(["detect", "--squares-x", "5", "--squares-y", "7", *map(str, frames), "--out", str(flags)]) == 0
    assert [e["corners"] for e in json.loads(flags.read_text())["images"]] == [e["corners"] for e in d["images"]]


def test_never_behind_opencv_on_the_real_frames():
    """Wherever findChessboardCornersSB or the classic findChessboardCorners finds the whole board
    in the real fisheye frames (../shared/real), ours finds the whole board too, and where both
    do, the corners are the same within a few pixels (OpenCV's own differ by up to 8.8 px on
    these frames: the classic corners are not refined). right-0000.png of the stereo head, a clear
    board in motion blur, was missed before every frame was allowed its half-resolution reading."""
    from calib_eval.detection.real_frames import SETS, evaluate_set

    for s in SETS:
        r = evaluate_set(s, progress=False)
        assert r["opencv_whole_ours_not"] == {"sb": [], "classic": []}, r["set"]
        assert r["whole"]["ours"] >= max(r["whole"]["sb"], r["whole"]["classic"])
        assert r["worst_agreement_px"]["sb"] < 3.0, r["set"]
    assert any(f["frame"] == "right-0000.png" and f["ours_whole"] for f in r["per_frame"])
