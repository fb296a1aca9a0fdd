"""Scoring of the AprilGrid evaluation: a peer's tags take their Kalibr corner ids by position;
recall counts detectable corners within 3 px of their own label, everything else is wrong."""

import numpy as np

from calib_eval.detection.tags import score_frame, tags_to_corners
from cotrain.targets import TargetConfig, make_target


def test_peer_tags_take_kalibr_ids_and_wrong_ones_count():
    g = make_target(TargetConfig(kind="aprilgrid", tag_cols=2, tag_rows=2))
    rng = np.random.default_rng(1)
    q = rng.uniform(0, 500, (g.n_corners, 2))
    k7 = g.tag_corners(3)  # tag 3's corners: Kalibr ids 10, 11, 15, 14
    np.testing.assert_array_equal(k7, [10, 11, 15, 14])
    tags = [(3, q[k7][[2, 0, 3, 1]] + 0.5), (99, q[g.tag_corners(0)])]  # any corner order; 99 is not on the board
    ids, xy = tags_to_corners(tags, g, q)
    assert sorted(ids[:4]) == [10, 11, 14, 15] and ids[4:] == [-1] * 4
    lab = {"corners": q.tolist(), "visible": [True] * g.n_corners, "tag_px": [20.0] * g.n_corners}
    lab["tag_px"][15] = 5.0  # too small to count: found, but neither recalled nor wrong
    s = score_frame(ids, xy, lab, 8.0)
    assert s["det"].sum() == g.n_corners - 1
    assert s["hit"].sum() == 3 and s["wrong"] == 4
    np.testing.assert_allclose(s["err"], [np.sqrt(0.5)] * 3)
