"""Scoring of the detection evaluation on hand-made predictions."""

import numpy as np
import pytest

from calib_eval.detection.evaluation import score, score_image

GT = np.array([[100.0, 100.0], [200.0, 100.0], [300.0, 100.0], [400.0, 100.0]])
VIS = np.array([True, True, True, False])
DET = np.array([True, True, True, False])


def test_score_image_learned():
    pred = [
        [0, 100.5, 100.0],  # exact within 0.5 px
        [1, 300.0, 100.0],  # wrong id (lands on corner 2)
        [2, 305.0, 100.0],
    ]  # right id, 5 px off
    s = score_image(pred, True, GT, VIS, DET)
    assert s["hits"] == [(0, 0.5)]
    assert s["n_detectable"] == 3 and s["n_reported"] == 3 and s["n_outliers"] == 2


def test_score_image_counts_right_ids_at_hidden_corners_apart():
    """A corner the labels call hidden (an occluder within 2 px of it), reported with its own id
    within 3 px, is neither a hit nor an outlier; with another id, or farther, it is an outlier.
    Matched by position (OpenCV), a report at a hidden corner counts the same way."""
    pred = [[3, 400.5, 100.0], [3, 405.0, 100.0], [2, 400.0, 100.0]]
    s = score_image(pred, True, GT, VIS, DET)
    assert s["hits"] == [] and s["n_hidden"] == 1 and s["n_outliers"] == 2
    s = score_image([[-1, 400.5, 100.0], [-1, 100.0, 101.0]], False, GT, VIS, DET)
    assert s["hits"] == [(0, 1.0)] and s["n_hidden"] == 1 and s["n_outliers"] == 0


def test_score_image_position_matched():
    pred = [[-1, 200.0, 101.0], [-1, 100.0, 100.0], [-1, 250.0, 100.0]]
    s = score_image(pred, False, GT, VIS, DET)
    assert sorted(s["hits"]) == [(0, 0.0), (1, 1.0)]
    assert s["n_outliers"] == 1  # the one between corners


def test_score_image_takes_a_symmetric_boards_equivalent_ids():
    """On a board that looks the same under a half turn (8 x 6 squares: 7 x 5 corners) one view's
    ids are defined up to that turn: the turned ids score as hits under the board's symmetries,
    and as outliers without them. Wrong ids stay wrong under every equivalent set."""
    from cotrain.targets import Checkerboard, TargetConfig

    board = Checkerboard(TargetConfig(squares_x=8, squares_y=6))
    (perm,) = board.symmetries()
    gt = np.stack(np.meshgrid(np.arange(7) * 30.0 + 100, np.arange(5) * 30.0 + 100), -1).reshape(-1, 2)
    vis = det = np.ones(len(gt), bool)
    turned = [[int(perm[i]), float(x), float(y)] for i, (x, y) in enumerate(gt[:10])]
    s = score_image(turned, True, gt, vis, det, symmetries=board.symmetries())
    assert len(s["hits"]) == 10 and s["n_outliers"] == 0
    s0 = score_image(turned, True, gt, vis, det)
    assert len(s0["hits"]) == 0 and s0["n_outliers"] == 10
    shifted = [[i + 1, float(x), float(y)] for i, (x, y) in enumerate(gt[:10])]  # one corner along: neither set of ids
    s1 = score_image(shifted, True, gt, vis, det, symmetries=board.symmetries())
    assert len(s1["hits"]) == 0 and s1["n_outliers"] == 10


def test_score_aggregates_and_empty_images():
    labels = [
        {
            "image": "a.png",
            "fov": 200,
            "has_target": True,
            "corners": GT.tolist(),
            "visible": VIS.tolist(),
            "detectable": DET.tolist(),
            "centre": [250.0, 100.0],
            "radius": 300.0,
        },
        {"image": "e.png", "fov": None, "has_target": False, "corners": [], "visible": [], "detectable": [], "centre": [0, 0], "radius": 1},
        {"image": "f.png", "fov": None, "has_target": False, "corners": [], "visible": [], "detectable": [], "centre": [0, 0], "radius": 1},
    ]
    preds = {
        "a.png": {"corners": [[0, 101.0, 100.0], [1, 200.0, 103.0], [3, 400.0, 100.0]], "ms": 10.0, "error": None, "has_id": True},
        "e.png": {"corners": [[5, 1.0, 1.0]], "ms": 20.0, "error": None, "has_id": True},  # a detection on an empty image
        "f.png": {"corners": [], "ms": 30.0, "error": None, "has_id": True},
    }
    r = score(preds, labels)
    row = r["per_fov"]["200"]
    # Corner 0 hit (1 px), corner 1 hit (3 px, the tolerance is inclusive), corner 2 missing; id 3 is
    # labelled hidden, reported at its place with its id: neither a hit nor an outlier.
    assert row["recall"] == pytest.approx(2 / 3)
    assert row["mean_error_px"] == pytest.approx(2.0) and row["median_error_px"] == pytest.approx(2.0)
    assert row["outlier_rate"] == 0.0 and row["n_hidden"] == 1
    assert r["false_images"] == 1 and r["n_empty"] == 2
    assert r["ms_per_image"] == pytest.approx(20.0)


def test_condition_frames_score_as_rows_of_their_own():
    """A frame rendered under a hard condition counts in its condition's row, not in its FoV's;
    the table lists the condition rows after the FoV rows."""
    from calib_eval.detection.evaluation import _table

    lab = {"image": "a.png", "has_target": True, "corners": GT.tolist(), "visible": VIS.tolist(), "detectable": DET.tolist()}
    lab |= {"centre": [250.0, 100.0], "radius": 300.0}
    labels = [{**lab, "fov": 200, "condition": None}, {**lab, "image": "b.png", "fov": 213.4, "condition": "motion blur"}]
    preds = {
        "a.png": {"corners": [[0, 100.0, 100.0], [1, 200.0, 100.0], [2, 300.0, 100.0]], "ms": 1.0, "error": None, "has_id": True},
        "b.png": {"corners": [[0, 100.0, 100.0]], "ms": 1.0, "error": None, "has_id": True},
    }
    r = score(preds, labels)
    assert set(r["per_fov"]) == {"200"} and set(r["per_condition"]) == {"motion blur"}
    assert r["per_fov"]["200"]["recall"] == 1.0 and r["per_condition"]["motion blur"]["recall"] == pytest.approx(1 / 3)
    table = _table({"learned": r}, [200])
    assert table.index("| 200 | learned | 1.000") < table.index("| motion blur | learned | 0.333")


def test_opencv_peers_go_on_past_an_unreadable_file(tmp_path):
    """calib-eval's OpenCV detectors over a folder where one file is no image: that file gets no
    corners and its error, and the next one is still read (a board drawn flat: its 6 x 4 inner
    corners found)."""
    import cv2

    from calib_eval.detection.evaluation import run_geometry
    from cotrain.targets import Checkerboard, TargetConfig

    board = Checkerboard(TargetConfig(squares_x=7, squares_y=5))
    page = np.full((300, 380), 255, np.uint8)
    for j in range(5):
        for i in range(7):
            if (i + j) % 2 == 0:
                page[40 + j * 40 : 80 + j * 40, 50 + i * 40 : 90 + i * 40] = 0
    (tmp_path / "a.png").write_bytes(b"not an image")
    cv2.imwrite(str(tmp_path / "b.png"), page)
    out = run_geometry("opencv_classic", [tmp_path / "a.png", tmp_path / "b.png"], board, progress=False)
    assert out["a.png"]["corners"] == [] and "not readable" in out["a.png"]["error"]
    assert len(out["b.png"]["corners"]) == 24 and out["b.png"]["error"] is None
