"""The geometric identifiability ceiling (calib_eval.detection.identifiability) on hand-made views."""

import numpy as np

from calib_eval.detection.identifiability import ceiling, identifiable

NX, NY = 9, 6
ALL = np.ones(NX * NY, bool)


def _ids(cols: range, rows: range) -> np.ndarray:
    return np.array([j * NX + i for j in rows for i in cols])


def test_whole_board_is_identifiable():
    assert identifiable(np.arange(NX * NY), ALL, NX, NY)


def test_interior_patch_without_context_is_ambiguous():
    """A 3x3 patch away from every edge, nothing else visible: shifting it by two squares keeps
    the colours and the board around it."""
    seen = _ids(range(3, 6), range(2, 5))
    vis = np.zeros(NX * NY, bool)
    vis[seen] = True
    assert not identifiable(seen, vis, NX, NY)


def test_one_row_is_ambiguous_two_rows_are_not():
    """The top corner row alone has no cells, so a half turn onto the bottom row (margins on the
    same sides) cannot be refuted; with two rows the cells' colours refute it (10 x 7 squares)."""
    for rows, expected in ((range(0, 1), False), (range(0, 2), True)):
        seen = _ids(range(NX), rows)
        vis = np.zeros(NX * NY, bool)
        vis[seen] = True
        assert identifiable(seen, vis, NX, NY) == expected


def test_corner_patch_needs_the_board_beyond_it():
    """6 x 3 corners at the top-left corner, margins seen on two sides: turned by 90 degrees it
    fits at another corner of the board with the same colours, unless the board is seen to go on
    beyond the patch (its neighbours there visible), which the turned placement puts off the board."""
    seen = _ids(range(0, 6), range(0, 3))
    only = np.zeros(NX * NY, bool)
    only[seen] = True
    assert not identifiable(seen, only, NX, NY)
    assert identifiable(seen, ALL, NX, NY)


def test_ceiling_weights_frames_by_detectable_corners():
    whole = {"fov": 180, "visible": ALL.tolist(), "detectable": ALL.tolist()}
    patch_det = np.zeros(NX * NY, bool)
    patch_det[_ids(range(3, 6), range(2, 5))] = True
    patch = {"fov": 180, "visible": patch_det.tolist(), "detectable": patch_det.tolist()}
    r = ceiling([whole, patch], NX, NY)["all"]
    assert r["detectable"] == 54 + 9
    assert abs(r["from_detectable"] - 54 / 63) < 1e-12
