"""Identity (cotrain.detect.identity): placements of hand-made lattices, margin evidence and board symmetries."""

import numpy as np
import pytest

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.identity import assign_ids, canonical_ids, edge_evidence
from cotrain.detect.lattice import Lattice
from cotrain.detect.saddle import smooth_for
from cotrain.targets import ROTATIONS, Checkerboard, TargetConfig, board_symmetries
from tests.detect.boards import BOARD, NX, NY, board_image, warped_board_image


def _board_ab() -> tuple[np.ndarray, np.ndarray]:
    ids = np.arange(NX * NY)
    return ids, np.stack([ids % NX, ids // NX], 1)


@pytest.mark.parametrize("rot", [0, 1, 2, 3])
def test_whole_board_is_identified_by_geometry_alone(rot):
    """With uninformative network maps, a fully seen board is placed by its extent and the checker
    colours alone (a 10 x 7 board is not symmetric under a half turn)."""
    ids, ij = _board_ab()
    ab = ij @ ROTATIONS[rot]  # the lattice as seen, turned by rot quarter turns (R^-1 = R^T)
    black = {(i, j): (i + j) % 2 == 0 for i in range(NX - 1) for j in range(NY - 1)}
    dark = {}
    for (i, j), b in black.items():
        quad = np.array([[i, j], [i + 1, j], [i, j + 1], [i + 1, j + 1]]) @ ROTATIONS[rot]
        dark[tuple(quad.min(0))] = 1.0 if b else -1.0
    flat_c = np.full((len(ab), NX + 2), -np.log(NX + 2))
    flat_r = np.full((len(ab), NY + 2), -np.log(NY + 2))
    got, _, margin, *_ = assign_ids(ab, flat_c, flat_r, dark, BOARD, GridConfig())
    np.testing.assert_array_equal(got, ids)
    assert margin > 10


def test_partial_lattice_follows_the_network_votes():
    """A 3 x 3 patch: geometry allows many placements; column / row votes pick one."""
    ids, ij = _board_ab()
    sel = (ij[:, 0] >= 4) & (ij[:, 0] < 7) & (ij[:, 1] >= 2) & (ij[:, 1] < 5)
    ab = ij[sel] - [4, 2]
    lc = np.full((len(ab), NX + 2), np.log(0.05))
    lr = np.full((len(ab), NY + 2), np.log(0.05))
    lc[np.arange(len(ab)), ij[sel, 0] + 1] = np.log(0.5)
    lr[np.arange(len(ab)), ij[sel, 1] + 1] = np.log(0.5)
    got, _, margin, *_ = assign_ids(ab, lc, lr, {}, BOARD, GridConfig())
    np.testing.assert_array_equal(got, ids[sel])
    assert margin > 5


def test_margin_evidence_on_a_lattice_one_row_deep():
    """A lattice of only the top corner row: the outward step is the sideways step turned by 90
    degrees, the white margin is found above every corner, and nothing is claimed below (the
    squares go on there)."""
    img, q = board_image()
    ids = np.arange(NX)[q[:NX, 0] < img.shape[1] - 12]  # row 0, inside the image
    lat = Lattice(q[ids], np.stack([ids, np.zeros_like(ids)], 1), np.zeros(len(ids), bool))
    ev = edge_evidence(smooth_for(img, -1), lat)
    up = {k for k, da, db, e in ev if (da, db) == (0, -1) and e > 0.8}
    assert up == set(range(len(ids)))
    assert not [e for e in ev if (e[1], e[2]) == (0, 1)]
    # The row's first corner has no neighbour across the left direction: the sideways step is the
    # step behind it turned by 90 degrees, and the left margin is found too.
    assert {k for k, da, db, e in ev if (da, db) == (-1, 0) and e > 0.8} == {0}


def test_margin_evidence_is_the_paper_not_a_light_occluder():
    """The top corner row of a board lit at half (white squares 0.46): the margin above it, paper
    as white as the squares, is evidence that the board ends there. Where something far brighter
    than the squares' white lies there instead (0.9: a light occluder along the row, the scene),
    it is no margin of this print and gives no evidence (a light occluder over the last square
    row read as margin placed a whole board a row off on a held-out set)."""
    img, q = board_image()
    dim = img * 0.5
    ids = np.arange(NX)[q[:NX, 0] < img.shape[1] - 12]
    lat = Lattice(q[ids], np.stack([ids, np.zeros_like(ids)], 1), np.zeros(len(ids), bool))
    up = lambda ev: {k for k, da, db, e in ev if (da, db) == (0, -1) and e > 0.8}  # noqa: E731
    assert up(edge_evidence(smooth_for(dim, -1), lat)) == set(range(len(ids)))
    lit = dim.copy()
    margin_above = (np.arange(img.shape[0])[:, None] < 36) & (img > 0.9)  # above square row 0 (y < 36), the margin
    lit[margin_above] = 0.9
    assert not up(edge_evidence(smooth_for(lit, -1), lat))


def test_board_symmetries_of_known_boards():
    """Turns that map a board onto itself, colours included: none for 10 x 7 squares, the half
    turn for 7 x 5 and 6 x 6, all three turns for 5 x 5 (squares; inner corners are one less)."""
    assert board_symmetries(9, 6) == ()
    for nx, ny, n in ((6, 4, 1), (5, 5, 1), (4, 4, 3), (7, 5, 1)):
        perms = board_symmetries(nx, ny)
        assert len(perms) == n
        ids = np.arange(nx * ny)
        for perm in perms:
            assert sorted(perm) == list(ids) and (perm != ids).any()
            # Which diagonal of a corner is black ((i + j) mod 2 in board axes) is kept by the half
            # turn and swapped by a quarter turn, which swaps the diagonals themselves.
            half = np.array_equal(perm[perm], ids)
            kept = (perm % nx + perm // nx) % 2 == (ids % nx + ids // nx) % 2
            assert kept.all() if half else not kept.any()
    half = board_symmetries(6, 4)[0]
    np.testing.assert_array_equal(half[[0, 5, 18, 23]], [23, 18, 5, 0])


@pytest.mark.parametrize("rot", [0, 1, 2, 3])
def test_symmetric_board_is_placed_up_to_its_half_turn(rot):
    """A whole 7 x 5 board (symmetric under a half turn) with uninformative votes: the half-turned
    placement is the same view, not a competitor, so the margin is large; the reported ids are the
    ones that put id 0 towards the image's top left."""
    board = Checkerboard(TargetConfig(squares_x=7, squares_y=5))
    nx, ny = board.nx, board.ny
    ids = np.arange(nx * ny)
    ij = np.stack([ids % nx, ids // nx], 1)
    ab = ij @ ROTATIONS[rot]
    dark = {}
    for i in range(nx - 1):
        for j in range(ny - 1):
            quad = np.array([[i, j], [i + 1, j], [i, j + 1], [i + 1, j + 1]]) @ ROTATIONS[rot]
            dark[tuple(quad.min(0))] = 1.0 if (i + j) % 2 == 0 else -1.0
    got, _, margin, *_ = assign_ids(ab, np.zeros((len(ab), nx + 2)), np.zeros((len(ab), ny + 2)), dark, board, GridConfig())
    assert margin > 10
    assert np.array_equal(got, ids) or np.array_equal(got, board_symmetries(nx, ny)[0][ids])
    xy = 40.0 * ab  # the lattice as the image shows it (a x b > 0, x right, y down)
    canon = canonical_ids(got, xy, board)
    assert np.array_equal(np.sort(canon), ids)
    k0, k1 = int(np.nonzero(canon == 0)[0][0]), int(np.nonzero(canon == nx * ny - 1)[0][0])
    assert xy[k0].sum() < xy[k1].sum()  # id 0 is the end of the board nearer the top left
    # An asymmetric board keeps its ids.
    np.testing.assert_array_equal(canonical_ids(np.array([0, 1, -1]), np.zeros((3, 2)), BOARD), [0, 1, -1])


def test_geometry_margin_leaves_out_the_network_votes():
    """The top two corner rows with the white margin seen left, right and above: the geometry
    alone places them (its margin is what the margin evidence, colours and extent give). Row votes
    that favour the placement one row lower lower the margin, not the geometry's."""
    ids, ij = _board_ab()
    sel = ij[:, 1] < 2
    ab = ij[sel]
    dark = {(i, 0): 1.0 if i % 2 == 0 else -1.0 for i in range(NX - 1)}
    edges = [(k, -1, 0, 1.0) for k, (i, j) in enumerate(ab) if i == 0]
    edges += [(k, 1, 0, 1.0) for k, (i, j) in enumerate(ab) if i == NX - 1]
    edges += [(k, 0, -1, 1.0) for k, (i, j) in enumerate(ab) if j == 0]
    flat_c = np.full((len(ab), NX + 2), -np.log(NX + 2))
    flat_r = np.full((len(ab), NY + 2), -np.log(NY + 2))
    cfg = GridConfig()
    plain = assign_ids(ab, flat_c, flat_r, dark, BOARD, cfg, edges)
    np.testing.assert_array_equal(plain.ids, ids[sel])
    assert plain.geometry_margin == pytest.approx(plain.margin)  # flat votes add nothing
    lower = flat_r.copy()
    lower[np.arange(len(ab)), ab[:, 1] + 2] = np.log(0.9)  # votes for one row further down
    lower[np.arange(len(ab)), ab[:, 1] + 1] = np.log(0.05)
    swayed = assign_ids(ab, flat_c, lower, dark, BOARD, cfg, edges)
    np.testing.assert_array_equal(swayed.ids, ids[sel])
    assert swayed.margin < plain.margin - 10
    assert swayed.geometry_margin == pytest.approx(plain.geometry_margin)


def test_votes_alone_place_a_board_only_where_turned_on():
    """The grid pass's acceptance: where the geometry cannot tell the best placement from another
    (a patch that fits the board turned as well), the shipped settings report nothing, however
    sure the network's votes; with ``votes_alone`` (as the tuning table scores every placement)
    they place it by ``min_margin``; where the geometry backs it, ``min_margin_backed`` is
    enough, even where the votes lean the other way by a few nats (an over-exposed frame, whose
    white the network was not trained on: geometry 15 ahead, votes 5 behind)."""
    from cotrain.detect.grid_pass import placement_is_sure

    shipped = GridConfig()
    assert placement_is_sure(15.0 - 5.0, 15.0, shipped)
    assert not placement_is_sure(20.0, shipped.min_geometry_margin - 1, shipped)  # backed too little: min_margin
    assert not placement_is_sure(1e6, 0.0, shipped) and not placement_is_sure(1e6, -3.0, shipped)
    assert placement_is_sure(shipped.min_margin + 1, 5.0, shipped)
    cfg = GridConfig(votes_alone=True)
    assert placement_is_sure(cfg.min_margin + 1, 0.0, cfg)
    assert not placement_is_sure(cfg.min_margin - 1, 0.0, cfg)  # votes alone, under min_margin
    assert placement_is_sure(cfg.min_margin_backed + 1, cfg.min_geometry_margin, cfg)
    assert not placement_is_sure(cfg.min_margin_backed - 1, 100.0, cfg)


def test_margin_evidence_where_the_squares_shrink_towards_the_edge():
    """Columns shrink by 0.6 per square towards the board's right edge, as near a fisheye's rim:
    the last square is 30 px where the step before it is 50 px, 0.6 of it, too short for an end of
    the squares one step out. Read along the step the lattice would take next (33 px), the white
    margin is found beside every corner of the last column; on the left the squares go on, and
    nothing is claimed there."""
    q_ratio = 1 / 0.6  # each square towards the left is this much wider
    x_end = 280.0  # where the squares end (u = 10), then half a square of margin

    def to_pixels(u, v):
        return x_end - 30 * (q_ratio ** (10 - np.asarray(u, float)) - 1) / (q_ratio - 1), 20 + 30 * np.asarray(v, float)

    def to_board(x, y):
        arg = np.clip(1 + (x_end - x) * (q_ratio - 1) / 30, 1e-6, None)
        return 10 - np.log(arg) / np.log(q_ratio), (y - 20) / 30

    img, q = warped_board_image(to_board, to_pixels, (300, 260))
    ids = np.arange(NX * NY)
    cols = ids % NX
    keep = cols >= 6  # corner columns 6-8: x = 117, 200, 250 (the column before is off the image)
    lat = Lattice(q[keep], np.stack([cols[keep] - 6, ids[keep] // NX], 1), np.zeros(keep.sum(), bool))
    ev = edge_evidence(smooth_for(img, -1), lat)
    right = {k for k, da, db, e in ev if (da, db) == (1, 0) and e > 0.8}
    assert right == set(np.nonzero(cols[keep] == 8)[0])
    assert not [e for e in ev if (e[1], e[2]) == (-1, 0)]


def test_one_verified_corner_off_the_board_backs_a_placement():
    """A corner patch of 16 corners, 7 columns at its widest and 4 rows, with the board's white
    margin seen below and left of it (an over-exposed frame's lattice): turned by a quarter it
    fits the board too, with one corner off it and every margin where the board ends. That one
    corner is all the geometry has against the turned placement: with the shipped settings it is
    enough to back the placement (``offboard_penalty`` = ``min_geometry_margin``), so network
    votes that beat the runner-up by ``min_margin_backed`` report it; at the former 10 per
    corner it was not."""
    from cotrain.detect.grid_pass import placement_is_sure

    ids = np.array([18, 27, 28, 29, 36, 37, 38, 39, 40, 45, 46, 47, 48, 49, 50, 51])
    ab = np.stack([ids % NX, ids // NX], 1)
    seen = {tuple(x) for x in ab.tolist()}
    dark = {(i, j): (1.0 if (i + j) % 2 == 0 else -1.0) for i, j in seen if {(i + 1, j), (i, j + 1), (i + 1, j + 1)} <= seen}
    edges = [(k, 0, 1, 1.0) for k, (i, j) in enumerate(ab) if j == NY - 1 and i < 6]  # the margin below (51: a tip)
    edges += [(k, -1, 0, 1.0) for k, (i, j) in enumerate(ab) if i == 0]  # and left
    flat_c = np.full((len(ab), NX + 2), -np.log(NX + 2))
    flat_r = np.full((len(ab), NY + 2), -np.log(NY + 2))
    shipped = GridConfig()
    placed = assign_ids(ab, flat_c, flat_r, dark, BOARD, shipped, edges)
    np.testing.assert_array_equal(placed.ids, ids)
    assert placed.geometry_margin == pytest.approx(shipped.offboard_penalty)
    assert placed.geometry_margin >= shipped.min_geometry_margin
    assert placement_is_sure(shipped.min_margin_backed + 1, placed.geometry_margin, shipped)
    former = GridConfig(offboard_penalty=10.0)
    before = assign_ids(ab, flat_c, flat_r, dark, BOARD, former, edges)
    assert before.geometry_margin == pytest.approx(10.0)
    assert not placement_is_sure(former.min_margin_backed + 1, before.geometry_margin, former)


def test_a_corner_without_extent_weight_gives_the_geometry_no_margin():
    """Column 0 of the board, whole (6 corners), and column 1, with one more corner beyond its end
    (as a board's outer corner against the dark beyond the image circle's rim makes: a half X).
    Taken as a verified corner, it puts the lattice along a 9-corner row, a quarter turn off, by
    one off-board penalty; weighted 0 (``extent_weight``), the geometry cannot tell the two apart."""
    ids, ij = _board_ab()
    sel = ij[:, 0] < 2
    ab = np.concatenate([ij[sel], [[0, NY]]])  # the last: one step past the column's end
    seen = {tuple(x) for x in ab.tolist()}
    dark = {(i, j): (1.0 if (i + j) % 2 == 0 else -1.0) for i, j in seen if {(i + 1, j), (i, j + 1), (i + 1, j + 1)} <= seen}
    edges = [(k, -1, 0, 1.0) for k, (i, j) in enumerate(ab) if i == 0]  # the margin left of column 0 ...
    edges += [(k, 0, -1, 1.0) for k, (i, j) in enumerate(ab) if j == 0]  # ... and above row 0
    flat_c = np.full((len(ab), NX + 2), -np.log(NX + 2))
    flat_r = np.full((len(ab), NY + 2), -np.log(NY + 2))
    cfg = GridConfig()
    fooled = assign_ids(ab, flat_c, flat_r, dark, BOARD, cfg, edges)
    assert (fooled.ids >= 0).all()  # the extra corner on the board: the lattice lies along a row
    assert not np.array_equal(fooled.ids[:-1], ids[sel])
    assert fooled.geometry_margin == pytest.approx(cfg.offboard_penalty)
    weight = np.ones(len(ab))
    weight[-1] = 0.0
    unsure = assign_ids(ab, flat_c, flat_r, dark, BOARD, cfg, edges, extent_weight=weight)
    assert unsure.geometry_margin == pytest.approx(0.0)
    # Corners weighted 1 are the shipped penalty: the same placement and margins as without weights.
    same = assign_ids(ab, flat_c, flat_r, dark, BOARD, cfg, edges, extent_weight=np.ones(len(ab)))
    np.testing.assert_array_equal(same.ids, fooled.ids)
    assert (same.margin, same.geometry_margin) == (fooled.margin, fooled.geometry_margin)


def test_board_goes_on_where_the_next_corner_lies_beyond_a_short_prediction():
    """``board_goes_on`` on a fronto-parallel board of 30 px squares: from corner (4, 3) with a
    predicted step of 20 px (stale, as where squares grow fast) the next corner 1.5 steps down is
    there, with the checker edge running to it; without that corner among the candidates, or in a
    direction 45 deg off, nothing is. Two squares on, with the corner between them missing, the
    edge changes sides half-way. From the last row (4, 5), where the board ends, the junction one
    step down lies where the last squares' side meets the white margin: the edge runs to it, but
    two of its quadrants are margin and its colours flip by half of the corner's, under
    ``goes_on_min_alternation`` (0.7; at 0.4 it would pass for the board going on)."""
    from dataclasses import replace

    from cotrain.detect.identity import board_goes_on

    cfg = GridConfig()
    img, q = board_image(sq=30, org=(30, 20), size=(360, 290))
    blur = smooth_for(img, -1)
    contrast = 0.84
    right = np.array([30.0, 0.0])

    def lighter_below(k: int) -> np.ndarray:  # the side of the lighter of the two squares below corner k
        return right if img[int(q[k, 1]) + 8, int(q[k, 0]) + 8] > 0.5 else -right

    k = 3 * NX + 4
    down = np.array([0.0, 20.0])
    assert board_goes_on(blur, q[k], down, right, lighter_below(k), q, contrast, cfg)
    without_next = np.delete(q, k + NX, axis=0)
    assert not board_goes_on(blur, q[k], down, right, lighter_below(k), without_next, contrast, cfg)
    assert not board_goes_on(blur, q[k], down + right * 2 / 3, right, lighter_below(k), q, contrast, cfg)
    assert not board_goes_on(blur, q[k], np.array([0.0, 40.0]), right, lighter_below(k), without_next, contrast, cfg)
    last = 5 * NX + 4
    at_margin = np.vstack([q, q[last] + [0.0, 30.0]])
    step = np.array([0.0, 30.0])
    assert not board_goes_on(blur, q[last], step, right, lighter_below(last), at_margin, contrast, cfg)
    loose = replace(cfg, goes_on_min_alternation=0.4)
    assert board_goes_on(blur, q[last], step, right, lighter_below(last), at_margin, contrast, loose)
