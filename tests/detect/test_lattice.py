"""Lattice growth helpers (cotrain.detect.lattice): step prediction and skipped-corner checks."""

import numpy as np
import pytest

from cotrain.detect.lattice import Lattice, next_step, skipped_corners, values_at
from cotrain.detect.saddle import saddle_response
from tests.detect.boards import NX, NY, board_image


def test_lattices_with_skipped_corners_are_recognised():
    """The true lattice has no X-junction at its step midpoints or cell centres; one grown with
    double steps along a, or with knight's moves (two along, one across: colours still
    alternate), has them at most of its steps or cells."""
    img, q = board_image(size=(360, 260))
    response = saddle_response(img)

    def lattice(ij: list[tuple[int, int]], ab: list[tuple[int, int]]) -> Lattice:
        ids = [j * NX + i for i, j in ij]
        return Lattice(q[ids], np.array(ab), np.zeros(len(ab), bool))

    true = [(i, j) for i in range(NX) for j in range(NY)]
    assert skipped_corners(lattice(true, true), response) == 0.0
    double = [(2 * a, b) for a in range(4) for b in range(NY)]
    assert skipped_corners(lattice(double, [(a, b) for a in range(4) for b in range(NY)]), response) > 0.8
    knight = [(2 * a + 1, b - a + 3) for a in range(4) for b in range(3)]
    knight_ab = [(a, b) for a in range(4) for b in range(3)]
    assert all(0 <= i < NX and 0 <= j < NY for i, j in knight)
    assert skipped_corners(lattice(knight, knight_ab), response) > 0.8


def test_next_step_continues_a_perspective_line_and_an_arc():
    # Equal steps on a line seen in perspective: x = f X / Z along X = t, Z = 2 + 0.5 t.
    t = np.arange(4.0)
    p = np.stack([500 * t / (2 + 0.5 * t), 100 + 0 * t], 1)
    np.testing.assert_allclose(next_step(p[1] - p[0], p[2] - p[1]), p[3] - p[2], atol=1e-9)
    # ... and receding the other way (growing steps).
    p = np.stack([300 * t / (4 - 0.6 * t), 0 * t], 1)
    np.testing.assert_allclose(next_step(p[1] - p[0], p[2] - p[1]), p[3] - p[2], atol=1e-9)
    # Equal chords of a circle: the step turns by the same angle again.
    a = 0.25 * t
    p = 80 * np.stack([np.cos(a), np.sin(a)], 1)
    np.testing.assert_allclose(next_step(p[1] - p[0], p[2] - p[1]), p[3] - p[2], atol=1e-9)
    # Equal steps stay equal; the ratio and the turn are clamped.
    np.testing.assert_allclose(next_step(np.array([10.0, 0]), np.array([10.0, 0])), [10, 0])
    np.testing.assert_allclose(np.linalg.norm(next_step(np.array([10.0, 0]), np.array([40.0, 0]))), 80)
    w = next_step(np.array([10.0, 0]), np.array([0.0, 10]))
    assert np.degrees(np.arctan2(w[1], w[0])) == pytest.approx(120)


def test_growth_searches_saddles_only_where_colours_alternate(monkeypatch):
    """Corners missing from the candidates are found by a saddle search at their predicted spot.
    Where a predicted spot shows no alternating checker colours (here a grey occluder over part
    of the board) no saddle is searched, and the lattice is the same as when every spot is."""
    import cotrain.detect.lattice as lattice_mod
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import grow_lattice
    from cotrain.detect.saddle import fit_saddles

    sq, org = 24, (30, 30)
    img, q = board_image(sq=sq, org=org, size=(330, 250))  # the whole board and its margin
    img[org[1] + 3 * sq + 6 : org[1] + 6 * sq - 6, org[0] + 5 * sq + 6 : org[0] + 8 * sq - 6] = 0.5  # hides corners (5..6, 3..4)
    hidden = [j * NX + i for i in (4, 5, 6) for j in (2, 3, 4)]
    hidden = [k for k in hidden if 5 * sq + 6 < q[k, 0] - org[0] < 8 * sq - 6 and 3 * sq + 6 < q[k, 1] - org[1] < 6 * sq - 6]
    missing = [NX + 2, 2 * NX + 7]  # corners the candidates lack
    cand = np.delete(q, missing + hidden, 0) + 0.2
    calls = []

    def counting(grey, smoothed, xy, *args, **kw):
        calls.extend(xy.tolist())
        return fit_saddles(grey, smoothed, xy, *args, **kw)

    monkeypatch.setattr(lattice_mod, "fit_saddles", counting)
    cfg = GridConfig()
    grown = []
    for gate in (True, False):
        if not gate:
            monkeypatch.setattr(lattice_mod, "_fill_alternates", lambda *a: True)
        smoothed: dict[int, np.ndarray] = {}
        xy, ok, axes = fit_saddles(img, smoothed, cand, 4, cfg)
        assert ok.all()
        calls.clear()
        grown.append((grow_lattice(xy, axes, 0, img, cfg, smoothed), np.array(calls)))
    (gated, at_gated), (plain, at_plain) = grown
    assert len(hidden) == 4 and len(gated.ab) == NX * NY - len(hidden) and int(gated.filled.sum()) == len(missing)
    np.testing.assert_array_equal(gated.ab, plain.ab)
    np.testing.assert_allclose(gated.xy, plain.xy)

    def near(at: np.ndarray, k: int) -> bool:
        return bool(len(at)) and np.linalg.norm(at - q[k], axis=1).min() < 0.3 * sq

    assert all(near(at_gated, k) for k in missing)  # searched, and found
    assert all(near(at_plain, k) for k in hidden) and not any(near(at_gated, k) for k in hidden)
    assert len(at_gated) < len(at_plain)


def test_values_at_is_bilinear_for_any_number_of_points():
    """Known values of a linear ramp (bilinear sampling is exact on it), for one point, for more
    points than cv2.remap takes in one column (32767), and none; NaN outside the image."""
    H, W = 40, 50
    yy, xx = np.mgrid[0:H, 0:W].astype(np.float32)
    img = 2 * xx + 3 * yy
    rng = np.random.default_rng(0)
    for n in (1, 40000):
        p = rng.uniform([0, 0], [W - 1, H - 1], (n, 2))
        np.testing.assert_allclose(values_at(img, p), 2 * p[:, 0] + 3 * p[:, 1], atol=0.1)  # remap may round to 1/32 px
    assert values_at(img, np.zeros((0, 2))).shape == (0,)
    assert values_at(img, np.zeros((3, 4, 2))).shape == (3, 4)
    assert np.isnan(values_at(img, np.array([[-5.0, 3.0], [10.0, H + 5.0]]))).all()
