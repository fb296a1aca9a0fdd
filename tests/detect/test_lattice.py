"""Lattice growth helpers (cotrain.detect.lattice): step prediction and skipped-corner checks."""

import cv2
import numpy as np
import pytest

from cotrain.detect.lattice import Lattice, next_step, skipped_corners
from cotrain.detect.saddle import saddle_response
from cotrain.detect.sampling import values_at
from tests.detect.boards import NX, NY, board_image, warped_board_image


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
        np.testing.assert_allclose(values_at(img, p), 2 * p[:, 0] + 3 * p[:, 1], rtol=1e-6)  # float32 coordinates
    assert values_at(img, np.zeros((0, 2))).shape == (0,)
    assert values_at(img, np.zeros((3, 4, 2))).shape == (3, 4)
    assert np.isnan(values_at(img, np.array([[-5.0, 3.0], [10.0, H + 5.0]]))).all()
    # With channels: each channel as alone (for short and long lists), NaN outside in every one.
    stack = np.dstack([img, -img, img * 0.5])
    for n in (5, 3000):
        p = rng.uniform([0, 0], [W - 1, H - 1], (n, 2))
        got = values_at(stack, p)
        assert got.shape == (n, 3)
        for c in range(3):
            np.testing.assert_array_equal(got[:, c], values_at(np.ascontiguousarray(stack[..., c]), p))
    assert values_at(stack, np.zeros((0, 2))).shape == (0, 3)
    assert np.isnan(values_at(stack, np.array([[-5.0, 3.0]]))).all()


@pytest.mark.skipif(int(cv2.__version__.split(".")[0]) < 5, reason="OpenCV 4's remap rounds coordinates to 1/32 px")
def test_values_at_compiled_are_cv2_remaps_values():
    """A float32 image is sampled by compiled code: bit for bit what cv2.remap (INTER_LINEAR, a
    NaN border) gives, at random points, at whole pixels, on and beyond the last row and column,
    and at coordinates that are not finite."""
    rng = np.random.default_rng(4)
    H, W = 37, 53
    img = rng.random((H, W)).astype(np.float32)
    p = np.concatenate(
        [
            rng.uniform(-2, [W + 1, H + 1], (5000, 2)),
            rng.integers(-1, [W + 1, H + 1], (1000, 2)).astype(np.float64),
            [[W - 1, 3.0], [W - 1.5, H - 1], [-1e-7, 2.0], [np.nan, 1.0], [1.0, np.inf], [1e12, 2.0]],
        ]
    )
    flat = p.astype(np.float32)[:, None]
    want = cv2.remap(img, flat[..., 0], flat[..., 1], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=(np.nan,) * 4)[:, 0]
    got = values_at(img, p)
    assert got.dtype == np.float32
    np.testing.assert_array_equal(got, want)  # NaN where NaN
    assert np.isnan(got).sum() > 100 and np.isfinite(got).sum() > 4000


def test_step_has_edge_along_lattice_steps_only():
    """Between two lattice neighbours runs the edge of a black and a white square, with its bright
    side where the parent corner's quadrant contrast says; a knight's move (two along, one across)
    and a step out over the board's white margin have no such edge all along."""
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import _bright_side
    from cotrain.detect.sampling import diag_contrast, edge_contrasts, step_has_edge

    sq = 24
    img, q = board_image(sq=sq, org=(30, 30), size=(330, 250))
    cfg = GridConfig()
    sa, sb = np.array([sq, 0.0]), np.array([0.0, sq])
    k = 2 * NX + 3  # corner (3, 2)
    par = diag_contrast(img, q[k], sa, sb, cfg.diag_offset)
    depth = cfg.step_edge_depth * sq
    for da, db in ((1, 0), (-1, 0), (0, 1), (0, -1)):
        nb = q[k] + da * sa + db * sb
        assert step_has_edge(img, q[k], nb, _bright_side(da, db, sa, sb), depth, par, cfg)
        assert not step_has_edge(img, q[k], nb, -_bright_side(da, db, sa, sb), depth, par, cfg)  # the wrong side bright
    knight = q[k] + 2 * sa + sb
    assert not step_has_edge(img, q[k], knight, _bright_side(1, 0, sa, sb), depth, par, cfg)
    last = NX - 1 + 2 * NX  # corner (8, 2): the next one along a would lie on the white margin
    par_last = diag_contrast(img, q[last], sa, sb, cfg.diag_offset)
    assert not step_has_edge(img, q[last], q[last] + 1.6 * sa, _bright_side(1, 0, sa, sb), depth, par_last, cfg)
    # Known values: 0.84 (white minus black) on the three samples of a true step.
    np.testing.assert_allclose(np.abs(edge_contrasts(img, q[k], q[k] + sa, np.array([0.0, 1.0]), depth)), 0.84, atol=0.02)


def test_growth_follows_squares_that_grow_fast():
    """A board whose squares grow by 1.25x per column, in both directions (as toward the middle of
    a fisheye image from its rim; steps 7 to 52 px): the growth takes every corner, each at its own
    lattice place. Along a row, the step across that a corner inherits from its parent is stale
    by 1.25x per column; scaled as the step along changed, it is right again."""
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import grow_lattice
    from cotrain.detect.saddle import fit_saddles

    x0, first, ratio, cy = 20.0, 7.0, 1.25, 150.0  # column u starts at x0 + first (ratio^u - 1) / (ratio - 1)

    def to_pixels(u, v):
        return x0 + first * (ratio**u - 1) / (ratio - 1), cy + (v - 3.5) * first * ratio**u

    def to_board(x, y):
        u = np.log1p((x - x0) * (ratio - 1) / first) / np.log(ratio)
        return u, 3.5 + (y - cy) / (first * ratio**u)

    img, q = warped_board_image(to_board, to_pixels, (300, 300))
    cfg = GridConfig()
    smoothed: dict[int, np.ndarray] = {}
    xy, ok, axes = fit_saddles(img, smoothed, q + 0.3, 3, cfg)
    assert ok.all() and np.abs(xy - q).max() < 0.5
    ij = np.stack([np.arange(NX * NY) % NX, np.arange(NX * NY) // NX], 1)
    for seed in (4 * NX + 1, 4 * NX + 4, 2 * NX + 7):  # from small squares, the middle, large ones
        lat = grow_lattice(xy, axes, seed, img, cfg, smoothed)
        assert len(lat.ab) == NX * NY
        at = np.array([np.argmin(np.linalg.norm(xy - p, axis=1)) for p in lat.xy])
        assert len(set(at.tolist())) == NX * NY
        # one in-plane turn (the board seen from its printed side) maps every (a, b) to its (i, j)
        d, ab = ij[at] - ij[at[0]], lat.ab - lat.ab[0]
        turns = ([[1, 0], [0, 1]], [[0, 1], [-1, 0]], [[-1, 0], [0, -1]], [[0, -1], [1, 0]])
        assert any(np.array_equal(ab @ np.array(R), d) for R in turns)


def test_edge_neighbour_follows_the_edge_where_the_prediction_missed():
    """With a predicted step 1.5x too long (stale, as where squares shrink fast), the walk along
    the checker edge finds the true neighbour, the nearest candidate with the edge all along
    (not the one two squares on); a direction 45 deg off the lattice, a candidate already offered,
    or a step out from the board's last column find nothing."""
    from scipy.spatial import cKDTree

    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import _bright_side, edge_neighbour
    from cotrain.detect.saddle import fit_saddles
    from cotrain.detect.sampling import diag_contrast

    sq = 24
    img, q = board_image(sq=sq, org=(30, 30), size=(330, 250))
    cfg = GridConfig()
    xy, ok, axes = fit_saddles(img, {}, q + 0.3, 4, cfg)
    assert ok.all()
    tree = cKDTree(xy)
    sa, sb = np.array([sq, 0.0]), np.array([0.0, sq])
    k = 2 * NX + 3  # corner (3, 2)
    par = diag_contrast(img, xy[k], sa, sb, cfg.diag_offset)
    bright = _bright_side(1, 0, sa, sb)
    used = {k}
    found = edge_neighbour(img, xy[k], 1.5 * sa, bright, par, xy, axes, tree, used, cfg)
    assert found is not None and np.linalg.norm(found - q[k + 1]) < 0.3
    assert k + 1 in used  # offered once, as match_corner does
    assert edge_neighbour(img, xy[k], 1.5 * sa, bright, par, xy, axes, tree, used, cfg) is None  # the next one is two squares on
    assert edge_neighbour(img, xy[k], sa + sb, bright, par, xy, axes, tree, {k}, cfg) is None
    last = 2 * NX + NX - 1  # corner (8, 2)
    par_last = diag_contrast(img, xy[last], sa, sb, cfg.diag_offset)
    assert edge_neighbour(img, xy[last], sa, bright, par_last, xy, axes, tree, {last}, cfg) is None


def test_rim_cut_tip_corner_needs_edges_along_both_lattice_axes(monkeypatch):
    """A corner whose window the image border cuts, at a lattice tip (one neighbour): its fitted
    edges must follow the lattice line to that neighbour and, along the other axis, the direction
    a neighbour across measures. Where a square's edge meets the border the half-X has the border
    as its second edge and is dropped; a true X-junction there is kept. (The saddle fit is
    replaced by one that returns the given edge directions, so the rule is tested alone.)"""
    import math

    import cotrain.detect.lattice as lattice_mod
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import verify_lattice

    th = math.radians(40)
    ea, eb = np.array([math.cos(th), math.sin(th)]), np.array([-math.sin(th), math.cos(th)])  # lattice axes in the image
    ab = np.array([(i, j) for j in range(3) for i in range(4)] + [(1, -1)])
    xy = np.array([80.0, 6.5]) + 20.0 * (ab[:, :1] * ea + ab[:, 1:] * eb)
    tip = len(ab) - 1
    assert 2.0 < xy[tip, 1] < 6.0  # next to the top border
    rim_dist = np.tile(np.arange(120, dtype=np.float32)[:, None], (1, 200))  # distance to the top border
    grey = np.zeros((120, 200), np.float32)

    def run(tip_axes: np.ndarray, borrowed: bool) -> set:
        def fake_fit(grey_, smoothed, q, half, cfg, rim_dist=None):
            axes = np.tile(np.stack([ea, eb])[None], (len(q), 1, 1))
            axes[np.linalg.norm(q - xy[tip], axis=1) < 1e-6] = tip_axes
            return q.copy(), np.ones(len(q), bool), axes

        monkeypatch.setattr(lattice_mod, "fit_saddles", fake_fit)
        out = verify_lattice(Lattice(xy, ab, np.zeros(len(ab), bool)), grey, GridConfig(rim_borrowed_axes=borrowed), {}, rim_dist)
        return {tuple(t) for t in out.ab.tolist()}

    half_x = np.stack([eb, np.array([1.0, 0.0])])  # the square's edge along b, then the border
    everything = {tuple(t) for t in ab.tolist()}
    assert run(half_x, True) == everything - {(1, -1)}
    assert run(half_x, False) == everything  # without the rule it stays
    assert run(np.stack([eb, ea]), True) == everything  # a true X-junction at the border stays


def test_a_corner_cut_by_the_image_border_alone_may_fit_its_edges_more_loosely(monkeypatch):
    """A corner whose window only the image's border cuts (the image circle's rim out of the
    window's reach) keeps fitted edges off its lattice lines (22 deg here): there is
    no dark rim there to make a half X-junction of a square's corner. Where the circle's rim is
    within reach, or no circle is known, the rim's limit (seed_axis_angle, 20 deg) holds. (The saddle
    fit is replaced by one that returns the given edge directions, so the rule is tested alone.)"""
    import math

    import cotrain.detect.lattice as lattice_mod
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import verify_lattice

    th = math.radians(40)
    ea, eb = np.array([math.cos(th), math.sin(th)]), np.array([-math.sin(th), math.cos(th)])
    ab = np.array([(i, j) for j in range(3) for i in range(4)])
    xy = np.array([80.0, 6.5]) + 20.0 * (ab[:, :1] * ea + ab[:, 1:] * eb)
    corner = 0  # (0, 0), 6.5 px below the top border, with neighbours along both axes
    rim_dist = np.tile(np.arange(120, dtype=np.float32)[:, None], (1, 200))
    turn = math.radians(22)  # its fitted edges 22 deg off the lattice lines: over the rim's limit
    rot = np.array([[math.cos(turn), -math.sin(turn)], [math.sin(turn), math.cos(turn)]])

    def fake_fit(grey_, smoothed, q, half, cfg, rim_dist=None):
        axes = np.tile(np.stack([ea, eb])[None], (len(q), 1, 1))
        axes[np.linalg.norm(q - xy[corner], axis=1) < 1e-6] = np.stack([rot @ ea, rot @ eb])
        return q.copy(), np.ones(len(q), bool), axes

    monkeypatch.setattr(lattice_mod, "fit_saddles", fake_fit)

    def kept(circle) -> bool:
        out = verify_lattice(Lattice(xy, ab, np.zeros(len(ab), bool)), np.zeros((120, 200), np.float32), GridConfig(), {}, rim_dist, circle)
        return (0, 0) in {tuple(t) for t in out.ab.tolist()}

    assert kept((np.array([100.0, 60.0]), 500.0))  # the circle's rim far outside the window: the border cuts it
    assert not kept((np.array([100.0, 200.0]), 195.0))  # the rim 0.5 px away
    assert not kept(None)  # no circle known: the dark region at the border may be the rim


def test_growth_remeasures_steps_where_the_lattice_bends():
    """A board bent into rings about a centre above the image (columns turn by 20 deg per square,
    squares shrink towards the centre, as near a fisheye's rim): a corner's step across, inherited
    along a row from its parent, is soon tens of degrees off. Measured again to the neighbours
    placed by the time the corner grows (``remeasure_steps``), the growth from a corner of the
    inner rings takes as many corners as have a saddle that fits, each at its own lattice place
    (measured: 49 of 54, the others out of the image); with inherited steps it stops short (44)."""
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import grow_lattice
    from cotrain.detect.saddle import fit_saddles

    cx, cy, r0, dr, dth, th0 = 320.0, -20.0, 330.0, 45.0, np.radians(20.0), -0.2

    def to_pixels(u, v):
        return cx + (r0 - dr * v) * np.cos(th0 + dth * u), cy + (r0 - dr * v) * np.sin(th0 + dth * u)

    def to_board(x, y):
        return (np.arctan2(y - cy, x - cx) - th0) / dth, (r0 - np.hypot(x - cx, y - cy)) / dr

    img, q = warped_board_image(to_board, to_pixels, (640, 480))
    smoothed: dict[int, np.ndarray] = {}
    xy, ok, axes = fit_saddles(img, smoothed, q + 0.3, 3, GridConfig())
    ij = np.stack([np.arange(NX * NY) % NX, np.arange(NX * NY) // NX], 1)
    assert ok.sum() >= 45 and np.abs(xy - q)[ok].max() < 0.5  # the others lie outside the image
    seed = 4 * NX + 4
    found = {}
    for remeasure in (False, True):
        cfg = GridConfig(remeasure_steps=remeasure)
        lat = grow_lattice(xy, axes, seed, img, cfg, dict(smoothed))
        at = np.array([np.argmin(np.linalg.norm(xy - p, axis=1)) for p in lat.xy])
        assert len(set(at.tolist())) == len(at)  # each corner once
        d, ab = ij[at] - ij[at[0]], lat.ab - lat.ab[0]
        turns = ([[1, 0], [0, 1]], [[0, 1], [-1, 0]], [[-1, 0], [0, -1]], [[0, -1], [1, 0]])
        assert any(np.array_equal(ab @ np.array(R), d) for R in turns)  # each at its own place
        found[remeasure] = len(at)
    assert found[True] >= ok.sum() and found[True] > found[False]


def test_a_seed_finds_its_neighbour_along_a_bent_side_of_a_large_square():
    """_bent_neighbour: where nothing lies within seed_axis_angle of the seed's edge direction, the
    nearest candidate at least seed_bend_px away within seed_bend_angle of it (either way) is the
    neighbour; nearer ones and ones farther off the direction are not."""
    import math

    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.lattice import _bent_neighbour

    cfg = GridConfig()
    u = np.array([1.0, 0.0])  # the seed's edge direction; the seed at the origin

    def at(dist: float, deg: float) -> np.ndarray:
        return dist * np.array([math.cos(math.radians(deg)), math.sin(math.radians(deg))])

    def neighbour(*points: np.ndarray, cfg: GridConfig = cfg):
        xy = np.array([np.zeros(2), *points])
        d = np.linalg.norm(xy[1:], axis=1)
        order = np.argsort(d)  # nearest first, as the KD-tree gives them
        return _bent_neighbour(xy[0], u, d[order], order + 1, xy, cfg)

    bent = at(60.0, 30.0)  # 30 deg off: outside seed_axis_angle (20), inside seed_bend_angle (35)
    got = neighbour(bent)
    assert got is not None and got[0] == pytest.approx(60.0) and np.allclose(got[1], bent)
    got = neighbour(at(90.0, 180 + 25.0), at(70.0, 180 - 30.0))  # the other way along u, nearest first
    assert got is not None and got[0] == pytest.approx(70.0)
    assert neighbour(at(0.9 * cfg.seed_bend_px, 30.0)) is None  # squares under seed_bend_px: the strict angle only
    assert neighbour(at(60.0, 40.0)) is None  # beyond seed_bend_angle
    assert neighbour(bent, cfg=GridConfig(seed_bend_angle=0.0)) is None  # off


def test_compiled_colour_tests_match_their_sampled_definitions():
    """The growth's compiled colour tests against their definitions through OpenCV's samplers:
    the quadrant contrast against four cv2.getRectSubPix values (to float32 rounding), inside the
    image and up to a few pixels beyond it (border replicated there, as getRectSubPix does); the
    edge test against the three contrasts of cv2.remap samples (NaN outside: no edge), on random
    steps over a smooth random image, both answers of the test among them."""
    import math

    import cv2

    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.sampling import diag_contrast, edge_contrasts, step_has_edge, value_at

    cfg = GridConfig()
    rng = np.random.default_rng(3)
    img = cv2.GaussianBlur(rng.random((120, 160)).astype(np.float32), (0, 0), 3.0)
    for _ in range(2000):
        p = rng.uniform([-4, -4], [164, 124])
        ea, eb = rng.normal(0, 8, 2), rng.normal(0, 8, 2)
        d1, d2 = 0.3 * (ea + eb), 0.3 * (ea - eb)
        ref = value_at(img, p + d2) + value_at(img, p - d2) - value_at(img, p + d1) - value_at(img, p - d1)
        assert diag_contrast(img, p, ea, eb, 0.3) == pytest.approx(ref, abs=1e-4)
    answers = []
    for _ in range(3000):
        p = rng.uniform([-3, -3], [163, 123])
        q = p + rng.normal(0, 12, 2)
        o = rng.normal(0, 1, 2)
        o /= np.linalg.norm(o)
        parent = rng.normal(0, 0.01)
        c = edge_contrasts(img, p, q, o, 3.0) * math.copysign(1.0, parent)
        ref = bool(np.all(c >= cfg.min_step_edge_contrast * abs(parent)))
        assert step_has_edge(img, p, q, o, 3.0, parent, cfg) == ref
        answers.append(ref)
    assert 0.02 < np.mean(answers) < 0.98
