"""The detector's grid pass (cotrain.detect.grid) against exact rendered labels and hand-made cases."""

import cv2
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cotrain.detect.grid import (
    ROTATIONS,
    GridConfig,
    Lattice,
    assign_ids,
    board_symmetries,
    canonical_ids,
    edge_evidence,
    fit_saddles,
    grid_pass,
    next_step,
    saddle_fit,
    saddle_response,
    skipped_corners,
    smooth_for,
)
from cotrain.render.renderer import RenderConfig, render_batch

NX, NY = 9, 6


def _x_junction(x0: float, y0: float, size: int = 41, angle: float = 0.3, ss: int = 8) -> np.ndarray:
    """A checker X-junction at (x0, y0), box-filtered by supersampling."""
    g = (np.arange(size * ss) + 0.5) / ss - 0.5
    X, Y = np.meshgrid(g, g)
    u = np.cos(angle) * (X - x0) + np.sin(angle) * (Y - y0)
    v = -np.sin(angle) * (X - x0) + np.cos(angle) * (Y - y0)
    img = np.where(u * v > 0, 0.9, 0.1)
    return img.reshape(size, ss, size, ss).mean((1, 3)).astype(np.float32)


def test_saddle_fit_known_subpixel_position_and_edge_directions():
    img = _x_junction(20.3, 19.65)
    xy, ok, axes = saddle_fit(smooth_for(img, 4), np.array([[19.0, 21.0]]), 4)
    assert ok[0]
    assert np.linalg.norm(xy[0] - [20.3, 19.65]) < 0.05
    # The zero lines of the fit are the checker edges: directions 0.3 and 0.3 + pi/2 rad.
    ang = sorted(np.mod(np.arctan2(axes[0, :, 1], axes[0, :, 0]), np.pi))
    assert ang[0] == pytest.approx(0.3, abs=0.05) and ang[1] == pytest.approx(0.3 + np.pi / 2, abs=0.05)


def test_saddle_fit_rejects_l_corner_and_edge():
    g = np.arange(41) - 20.0
    X, Y = np.meshgrid(g, g)
    l_corner = np.where((X > 0) & (Y > 0), 0.1, 0.9).astype(np.float32)
    edge = np.where(X > 0.3, 0.1, 0.9).astype(np.float32)
    for img in (l_corner, edge):
        _, ok, _ = saddle_fit(smooth_for(img, 4), np.array([[20.0, 20.0]]), 4)
        assert not ok[0]


def test_saddle_fit_next_to_the_rim_uses_the_part_that_is_seen():
    """An X-junction a few pixels from the dark rim of the image circle: the full window mixes in
    the rim (pulled off by a pixel, or no saddle at all); the fit over the pixels the blur has not
    mixed with the rim finds the corner, with a smaller window where the big one is cut too much."""
    truth = np.array([20.3, 19.65])
    start = np.array([[19.5, 20.5]])

    def cut_at(column: int) -> tuple[np.ndarray, np.ndarray]:
        img = _x_junction(*truth)
        allowed = np.ones_like(img, bool)
        allowed[:, column:] = False  # the black beyond the rim
        img[~allowed] = 0.0
        return img, cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)

    for column in (27, 25):  # 6.7 and 4.7 px from the corner
        img, rim_dist = cut_at(column)
        plain, ok_plain, _ = saddle_fit(smooth_for(img, 8), start, 8)
        assert not ok_plain[0] or np.linalg.norm(plain[0] - truth) > 0.5
        xy, ok, axes = fit_saddles(img, {}, start, 8, GridConfig(), rim_dist)
        assert ok[0] and np.linalg.norm(xy[0] - truth) < 0.1
        ang = sorted(np.mod(np.arctan2(axes[0, :, 1], axes[0, :, 0]), np.pi))
        assert ang[0] == pytest.approx(0.3, abs=0.1) and ang[1] == pytest.approx(0.3 + np.pi / 2, abs=0.1)
    # Closer than min_rim_px (3 px): not reported.
    img, rim_dist = cut_at(23)
    assert not fit_saddles(img, {}, start, 8, GridConfig(), rim_dist)[1][0]


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
    got, _, margin, _ = assign_ids(ab, flat_c, flat_r, dark, NX, NY, GridConfig())
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
    got, _, margin, _ = assign_ids(ab, lc, lr, {}, NX, NY, GridConfig())
    np.testing.assert_array_equal(got, ids[sel])
    assert margin > 5


def _oracle_maps(batch: dict, k: int, scale: float, h: int, w: int, noise: float, rng: np.random.Generator):
    """What a good network would output: corner score, board mask and noisy column / row maps."""
    q = (batch["corners"][k].numpy() + 0.5) * scale - 0.5
    ys, xs = np.mgrid[0:h, 0:w]
    prob = np.zeros((h, w))
    for j in np.nonzero(batch["visible"][k].numpy())[0]:
        c = (q[j] - 1.5) / 4
        prob = np.maximum(prob, np.exp(-((xs - c[0]) ** 2 + (ys - c[1]) ** 2) / (2 * 0.75**2)))
    uv4 = F.interpolate(batch["board_uv"][k : k + 1], size=(h, w), mode="area")[0].numpy()
    m4 = F.interpolate(batch["board_mask"][k : k + 1], size=(h, w), mode="area")[0, 0].numpy()

    def logp(x: np.ndarray, n: int) -> np.ndarray:
        cls = np.arange(-1, n + 1)[:, None, None]
        lg = -(((x + rng.normal(0, noise, x.shape))[None] - cls) ** 2) / (2 * 0.6**2)
        lg = np.where(m4[None] > 0.5, lg, 0.0)
        return lg - np.log(np.exp(lg).sum(0, keepdims=True))

    return prob, m4, logp(uv4[0], NX), logp(uv4[1], NY)


def test_grid_pass_on_rendered_images_with_oracle_network_maps():
    """Rendered fisheye frames (exact labels) and network maps made from the labels with noisy
    identity: most detectable corners come back with the right id and sub-0.15 px median error,
    no wrong id is reported, and nothing on a frame without the board."""
    torch.manual_seed(0)
    cfg = RenderConfig(height=360, width=640, p_no_target=0.0)
    batch = render_batch(cfg, list(range(10)), seed=77)
    rng = np.random.default_rng(0)
    scale, h, w = 0.6, 54, 96  # processing 384 x 216
    n_det = n_hit = n_bad = 0
    errs = []
    for k in range(10):
        grey = batch["image"][k, 0].numpy()
        maps = _oracle_maps(batch, k, scale, h, w, 0.5, rng)
        r = grid_pass(grey, scale, *maps, NX, NY, GridConfig())
        q = batch["corners_raw"][k].numpy()  # where every id projects, visible or not
        det = batch["visible"][k].numpy() & (batch["learnability"][k].numpy() > 0.2)
        n_det += det.sum()
        for i, p in zip(r.ids, r.xy):
            e = np.linalg.norm(p - q[i])
            n_hit += bool(e < 3 and det[i])
            n_bad += bool(e >= 3)
            if det[i]:
                errs.append(e)
    assert n_bad == 0
    assert n_hit / n_det > 0.6
    assert np.median(errs) < 0.15
    # No board: the network's maps are empty, so nothing is reported.
    empty = grid_pass(batch["image"][0, 0].numpy(), scale, np.zeros((h, w)), np.zeros((h, w)), *maps[2:], NX, NY, GridConfig())
    assert len(empty.ids) == 0


def _board_image(sq: int = 30, org: tuple[int, int] = (40, 36), size: tuple[int, int] = (200, 170)) -> tuple[np.ndarray, np.ndarray]:
    """A fronto-parallel 10 x 7 checkerboard (square (0, 0) black) with its white margin on grey
    background, cut by the image: returns the image and every corner id's pixel position."""
    ss = 4
    H, W = size[1] * ss, size[0] * ss
    ys, xs = (np.mgrid[0:H, 0:W] + 0.5) / ss - 0.5
    u, v = (xs - org[0]) / sq, (ys - org[1]) / sq  # board coordinates in squares
    img = np.full((H, W), 0.45)
    on_board = (u > -0.5) & (u < 10.5) & (v > -0.5) & (v < 7.5)
    img[on_board] = 0.92
    sqs = (u >= 0) & (u < 10) & (v >= 0) & (v < 7)
    black = (np.floor(u).astype(int) + np.floor(v).astype(int)) % 2 == 0
    img[sqs & black] = 0.08
    img = img.reshape(size[1], ss, size[0], ss).mean((1, 3)).astype(np.float32)
    ids = np.arange(NX * NY)
    q = np.stack([org[0] + (ids % NX + 1) * sq, org[1] + (ids // NX + 1) * sq], 1).astype(float)
    return img, q


def test_board_margin_pins_a_partial_view():
    """Only the board's top-left part is in the image; the network's votes are weak (right class
    0.2 against 0.07 for each other). The white margin seen beyond the top and left corner rows
    puts the right placement far ahead of the others; without that evidence it is much closer."""
    img, q = _board_image()
    H, W = img.shape
    inside = (q[:, 0] < W - 8) & (q[:, 1] < H - 8)
    h, w = 54, 96
    scale = min(384 / W, 216 / H)
    ys, xs = np.mgrid[0:h, 0:w]
    xin, yin = (xs * 4 + 1.5 + 0.5) / scale - 0.5, (ys * 4 + 1.5 + 0.5) / scale - 0.5  # input pixel of each cell
    col = np.clip(np.rint((xin - 40) / 30 - 1), -1, NX).astype(int)
    row = np.clip(np.rint((yin - 36) / 30 - 1), -1, NY).astype(int)
    lc = np.where(np.arange(-1, NX + 1)[:, None, None] == col[None], 0.2, 0.8 / (NX + 1))
    lr = np.where(np.arange(-1, NY + 1)[:, None, None] == row[None], 0.2, 0.8 / (NY + 1))
    ones = np.ones((h, w))
    with_edges = grid_pass(img, scale, ones, ones, np.log(lc), np.log(lr), NX, NY, GridConfig(min_margin=-np.inf))
    assert set(with_edges.ids) == set(np.nonzero(inside)[0])
    # Corners whose fit window is cut by the image border are fitted from the part that is seen:
    # a small bias, bounded here; the others are exact.
    err = np.linalg.norm(with_edges.xy - q[with_edges.ids], axis=1)
    cut = (H - 1 - q[with_edges.ids, 1] < 16) | (W - 1 - q[with_edges.ids, 0] < 16)  # window + blur reach the border
    assert cut.any() and err[cut].max() < 0.3 and err[~cut].max() < 0.1
    no_edges = grid_pass(img, scale, ones, ones, np.log(lc), np.log(lr), NX, NY, GridConfig(edge_weight=0.0, min_margin=-np.inf))
    assert with_edges.margin > no_edges.margin + 10


def test_margin_evidence_on_a_lattice_one_row_deep():
    """A lattice of only the top corner row: the outward step is the sideways step turned by 90
    degrees, the white margin is found above every corner, and nothing is claimed below (the
    squares go on there)."""
    img, q = _board_image()
    ids = np.arange(NX)[q[:NX, 0] < img.shape[1] - 12]  # row 0, inside the image
    lat = Lattice(q[ids], np.stack([ids, np.zeros_like(ids)], 1), np.zeros(len(ids), bool))
    ev = edge_evidence(smooth_for(img, -1), lat)
    up = {k for k, da, db, e in ev if (da, db) == (0, -1) and e > 0.8}
    assert up == set(range(len(ids)))
    assert not [e for e in ev if (e[1], e[2]) == (0, 1)]
    # The row's first corner has no neighbour across the left direction: the sideways step is the
    # step behind it turned by 90 degrees, and the left margin is found too.
    assert {k for k, da, db, e in ev if (da, db) == (-1, 0) and e > 0.8} == {0}


def test_lattices_with_skipped_corners_are_recognised():
    """The true lattice has no X-junction at its step midpoints or cell centres; one grown with
    double steps along a, or with knight's moves (two along, one across: colours still
    alternate), has them at most of its steps or cells."""
    img, q = _board_image(size=(360, 260))
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
    nx, ny = 6, 4
    ids = np.arange(nx * ny)
    ij = np.stack([ids % nx, ids // nx], 1)
    ab = ij @ ROTATIONS[rot]
    dark = {}
    for i in range(nx - 1):
        for j in range(ny - 1):
            quad = np.array([[i, j], [i + 1, j], [i, j + 1], [i + 1, j + 1]]) @ ROTATIONS[rot]
            dark[tuple(quad.min(0))] = 1.0 if (i + j) % 2 == 0 else -1.0
    got, _, margin, _ = assign_ids(ab, np.zeros((len(ab), nx + 2)), np.zeros((len(ab), ny + 2)), dark, nx, ny, GridConfig())
    assert margin > 10
    assert np.array_equal(got, ids) or np.array_equal(got, board_symmetries(nx, ny)[0][ids])
    xy = 40.0 * ab  # the lattice as the image shows it (a x b > 0, x right, y down)
    canon = canonical_ids(got, xy, nx, ny)
    assert np.array_equal(np.sort(canon), ids)
    k0, k1 = int(np.nonzero(canon == 0)[0][0]), int(np.nonzero(canon == nx * ny - 1)[0][0])
    assert xy[k0].sum() < xy[k1].sum()  # id 0 is the end of the board nearer the top left
    # An asymmetric board keeps its ids.
    np.testing.assert_array_equal(canonical_ids(np.array([0, 1, -1]), np.zeros((3, 2)), 9, 6), [0, 1, -1])
