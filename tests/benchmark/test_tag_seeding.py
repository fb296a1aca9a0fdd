"""The tag-seeding measurement's corner ids (calib_eval.benchmark.tag_seeding): aruco's four corners
of a tag get Kalibr's ids in ARUCO_TO_KALIBR's order, and tags not on the board are left out."""

import numpy as np

from calib_eval.benchmark.tag_seeding import ARUCO_TO_KALIBR, aruco_corners
from cotrain.targets import AprilGrid


def test_aruco_corners_get_kalibrs_ids_and_foreign_tags_are_left_out():
    board = AprilGrid()
    quad = np.array([[0.0, 0.0], [10.0, 0.0], [10.0, 10.0], [0.0, 10.0]])
    ids, xy = aruco_corners([(3, quad), (board.n_tags + 5, quad + 50)], board)
    kalibr = board.tag_corners(3)
    assert ids.tolist() == [int(kalibr[k]) for k in ARUCO_TO_KALIBR] and np.array_equal(xy, quad)
    assert sorted(ARUCO_TO_KALIBR) == [0, 1, 2, 3]  # each of the tag's corners once
    none_ids, none_xy = aruco_corners([], board)
    assert none_ids.shape == (0,) and none_xy.shape == (0, 2)
