"""The geometric identifiability ceiling (calib_eval.detection.identifiability) on hand-made views."""

import numpy as np

from calib_eval.detection.identifiability import ceiling, identifiable, off_board_in_view

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


def _grid_q(step: float = 40.0, origin: float = 100.0) -> np.ndarray:
    """Every corner's pixel position on an unbent view: (i, j) at origin + step * (i, j)."""
    i, j = np.meshgrid(np.arange(NX), np.arange(NY))
    return np.stack([i.ravel(), j.ravel()], 1) * step + origin


def test_off_board_places_in_view_known_values():
    """Corners at x = 100..420, y = 100..300 every 40 px: the places one step beyond the edges are
    at x = 60 / 460 and y = 60 / 340. A 800 x 330 image cuts off the row below; an image circle of
    radius 200 about the origin keeps the three places nearest it on the left and on top."""
    q = _grid_q()
    places = off_board_in_view(q, NX, NY, (800, 330))
    assert places == {(-1, j) for j in range(NY)} | {(NX, j) for j in range(NY)} | {(i, -1) for i in range(NX)}
    circle = off_board_in_view(q, NX, NY, (800, 400), centre=np.array([0.0, 0.0]), radius=200.0)
    assert circle == {(-1, 0), (-1, 1), (-1, 2), (0, -1), (1, -1), (2, -1)}


def test_a_board_one_corner_deep_has_no_place_to_extrapolate_across():
    """A row of 3 corners: the places beyond its ends are extrapolated along the row; above and
    below there is no inward neighbour, so those places are not claimed to be in view."""
    q = np.array([[100.0, 100.0], [140.0, 100.0], [180.0, 100.0]])
    assert off_board_in_view(q, 3, 1, (800, 400)) == {(-1, 0), (3, 0)}


def test_a_margin_beyond_the_image_identifies_nothing():
    """6 x 6 corners at the top-left corner span the board's height: the margin below the last row
    is what refutes the placement turned by 90 degrees onto the bottom-left corner. Where that
    margin lies below the image's edge, the view is ambiguous."""
    seen = _ids(range(0, 6), range(0, NY))
    vis = np.zeros(NX * NY, bool)
    vis[seen] = True
    q = _grid_q()
    assert identifiable(seen, vis, NX, NY)
    assert identifiable(seen, vis, NX, NY, off_board_in_view(q, NX, NY, (800, 400)))
    assert not identifiable(seen, vis, NX, NY, off_board_in_view(q, NX, NY, (800, 330)))


def test_ceiling_weights_frames_by_detectable_corners():
    whole = {"fov": 180, "visible": ALL.tolist(), "detectable": ALL.tolist()}
    patch_det = np.zeros(NX * NY, bool)
    patch_det[_ids(range(3, 6), range(2, 5))] = True
    patch = {"fov": 180, "visible": patch_det.tolist(), "detectable": patch_det.tolist()}
    r = ceiling([whole, patch], NX, NY)["all"]
    assert r["detectable"] == 54 + 9
    assert abs(r["from_detectable"] - 54 / 63) < 1e-12


def test_ceiling_with_the_image_size_reads_the_labels_positions():
    """The same view, its bottom margin in view or beyond a 330 px high image."""
    seen = _ids(range(0, 6), range(0, NY))
    vis = np.zeros(NX * NY, bool)
    vis[seen] = True
    lab = {"fov": 200, "visible": vis.tolist(), "detectable": vis.tolist(), "corners": _grid_q().tolist()}
    assert ceiling([lab], NX, NY)["all"]["from_detectable"] == 1.0
    assert ceiling([lab], NX, NY, (800, 400))["all"]["from_detectable"] == 1.0
    assert ceiling([lab], NX, NY, (800, 330))["all"]["from_detectable"] == 0.0
