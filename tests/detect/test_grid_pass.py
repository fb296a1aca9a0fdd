"""The whole grid pass (cotrain.detect.grid_pass) against exact rendered labels and a synthetic partial view."""

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.grid_pass import grid_pass
from cotrain.detect.lattice import Lattice
from cotrain.geometry.letterbox import Letterbox
from cotrain.render.renderer import RenderConfig, render_batch
from tests.detect.boards import BOARD, NX, NY, board_image


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
    box, h, w = Letterbox(640, 360, (216, 384)), 54, 96
    scale = box.scale
    assert scale == 0.6
    n_det = n_hit = n_bad = 0
    errs = []
    for k in range(10):
        grey = batch["image"][k, 0].numpy()
        maps = _oracle_maps(batch, k, scale, h, w, 0.5, rng)
        r = grid_pass(grey, box, *maps, BOARD, GridConfig())
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
    empty = grid_pass(batch["image"][0, 0].numpy(), box, np.zeros((h, w)), np.zeros((h, w)), *maps[2:], BOARD, GridConfig())
    assert len(empty.ids) == 0


def test_board_margin_pins_a_partial_view():
    """Only the board's top-left part is in the image; the network's votes are weak (right class
    0.2 against 0.07 for each other). The white margin seen beyond the top and left corner rows
    puts the right placement far ahead of the others; without that evidence it is much closer."""
    img, q = board_image()
    H, W = img.shape
    inside = (q[:, 0] < W - 8) & (q[:, 1] < H - 8)
    h, w = 54, 96
    box = Letterbox(W, H, (216, 384))
    scale = box.scale
    ys, xs = np.mgrid[0:h, 0:w]
    xin, yin = (xs * 4 + 1.5 + 0.5) / scale - 0.5, (ys * 4 + 1.5 + 0.5) / scale - 0.5  # input pixel of each cell
    col = np.clip(np.rint((xin - 40) / 30 - 1), -1, NX).astype(int)
    row = np.clip(np.rint((yin - 36) / 30 - 1), -1, NY).astype(int)
    lc = np.where(np.arange(-1, NX + 1)[:, None, None] == col[None], 0.2, 0.8 / (NX + 1))
    lr = np.where(np.arange(-1, NY + 1)[:, None, None] == row[None], 0.2, 0.8 / (NY + 1))
    ones = np.ones((h, w))
    with_edges = grid_pass(img, box, ones, ones, np.log(lc), np.log(lr), BOARD, GridConfig(min_margin=-np.inf, votes_alone=True))
    assert set(with_edges.ids) == set(np.nonzero(inside)[0])
    # Corners whose fit window is cut by the image border are fitted from the part that is seen:
    # a small bias, bounded here; the others are exact.
    err = np.linalg.norm(with_edges.xy - q[with_edges.ids], axis=1)
    cut = (H - 1 - q[with_edges.ids, 1] < 16) | (W - 1 - q[with_edges.ids, 0] < 16)  # window + blur reach the border
    assert cut.any() and err[cut].max() < 0.3 and err[~cut].max() < 0.1
    no_edges = grid_pass(
        img, box, ones, ones, np.log(lc), np.log(lr), BOARD, GridConfig(edge_weight=0.0, min_margin=-np.inf, votes_alone=True)
    )
    assert with_edges.margin > no_edges.margin + 10


def test_contrast_scaled_thresholds():
    """The contrast thresholds scale with the searched region's contrast (5th-95th percentile)
    under ``board_contrast``; a region of higher contrast keeps them."""
    from cotrain.detect.grid_pass import contrast_scaled

    cfg = GridConfig(board_contrast=0.5)
    grey = np.tile(np.linspace(0.3, 0.6, 400), (40, 1)).astype(np.float32)  # 5-95 %: 0.315 .. 0.585
    roi = np.ones_like(grey, bool)
    low = contrast_scaled(cfg, grey, roi)
    k = (0.585 - 0.315) / 0.5
    np.testing.assert_allclose(
        [low.min_saddle_contrast, low.min_edge_contrast],
        [cfg.min_saddle_contrast * k, cfg.min_edge_contrast * k],
        rtol=0.01,  # the percentiles are taken over every 4th pixel
    )
    assert low.board_contrast == pytest.approx(0.5 * k, rel=0.01)  # the contrast the thresholds now hold for
    flat = contrast_scaled(cfg, np.full_like(grey, 0.5), roi)  # no contrast: a quarter of the thresholds at most
    assert flat.min_saddle_contrast == cfg.min_saddle_contrast * 0.25 and flat.board_contrast == 0.5 * 0.25
    assert low.min_response == cfg.min_response and low.min_alternation == cfg.min_alternation  # shares stay
    assert contrast_scaled(cfg, np.tile(np.linspace(0, 1, 400), (40, 1)).astype(np.float32), roi) is cfg
    assert contrast_scaled(GridConfig(board_contrast=0.0), grey, roi) == GridConfig(board_contrast=0.0)


def test_grid_pass_on_a_grey_print():
    """Prints of grey on grey (black 0.3-0.4, white 0.55-0.65), rendered with exact labels and
    oracle network maps: with the thresholds scaled to the region's contrast the pass finds more
    corners than with them fixed (measured 244 against 234), in no frame fewer, every one with
    its right id."""
    cfg = RenderConfig(height=360, width=640, p_no_target=0.0, black_range=(0.3, 0.4), white_range=(0.55, 0.65))
    n = 12
    batch = render_batch(cfg, list(range(n)), seed=6)
    box, h, w = Letterbox(640, 360, (216, 384)), 54, 96
    found = {}
    for name, grid in (("scaled", GridConfig()), ("fixed", GridConfig(board_contrast=0.0))):
        found[name] = []
        for k in range(n):
            maps = _oracle_maps(batch, k, box.scale, h, w, 0.5, np.random.default_rng(k))
            r = grid_pass(batch["image"][k, 0].numpy(), box, *maps, BOARD, grid)
            e = np.linalg.norm(r.xy - batch["corners_raw"][k].numpy()[r.ids], axis=1)
            assert (e < 3).all(), (name, k)
            found[name].append(len(e))
    assert all(a >= b for a, b in zip(found["scaled"], found["fixed"])), found
    assert sum(found["scaled"]) > sum(found["fixed"]) + 5, found


def test_merge_lattices_joins_agreeing_lattices_of_the_board():
    """Two lattices of one board, grown from different seeds in their own lattice frames and each
    placed surely, overlap in two columns: their union has every corner once, at its own spot.
    A lattice placed one column off, one placed unsurely, and one that shares fewer corners than
    ``merge_min_shared`` are not joined; on a board that looks the same turned, a lattice placed
    up to that turn is joined with the best one's ids."""
    from cotrain.detect.grid_pass import merge_lattices
    from cotrain.detect.lattice import Lattice
    from cotrain.targets import Checkerboard, TargetConfig

    cfg = GridConfig()
    ids = np.arange(NX * NY)
    i, j = ids % NX, ids // NX
    q = np.stack([40.0 + 30 * i, 36.0 + 30 * j], 1)

    def lattice(sel: np.ndarray, ab: np.ndarray) -> Lattice:
        return Lattice(q[sel], ab, np.zeros(sel.sum(), bool))

    left, right = i <= 5, i >= 4
    best = lattice(left, np.stack([i[left] + 3, j[left] - 2], 1))  # any lattice frame
    other = lattice(right, np.stack([j[right], -i[right]], 1))  # another one, turned
    sure, unsure = (100.0, 50.0), (1.0, -5.0)
    lat, out = merge_lattices(best, ids[left], [(*sure[:1], other, ids[right], sure[1])], BOARD, cfg)
    order = np.argsort(out)
    np.testing.assert_array_equal(out[order], ids)
    np.testing.assert_allclose(lat.xy[order], q)
    np.testing.assert_array_equal(lat.ab[order], np.stack([i, j], 1))  # the board's own (i, j)

    shifted = np.where(i[right] < NX - 1, ids[right] + 1, -1)  # placed one column off
    few = right & (i >= 5) & (j == 0)  # shares one corner (id 5)
    for margin, o, oids, geo in [
        (sure[0], other, shifted, sure[1]),
        (unsure[0], other, ids[right], unsure[1]),
        (sure[0], lattice(few | (i >= 6), np.stack([i[few | (i >= 6)], j[few | (i >= 6)]], 1)), ids[few | (i >= 6)], sure[1]),
    ]:
        lat, out = merge_lattices(best, ids[left], [(margin, o, oids, geo)], BOARD, cfg)
        np.testing.assert_array_equal(out, ids[left])

    square = Checkerboard(TargetConfig(squares_x=7, squares_y=7))  # 6 x 6 corners, the same turned by 90 deg
    assert square.symmetries()
    perm = square.symmetries()[0]
    sid = np.arange(36)
    si, sj = sid % 6, sid // 6
    sq = np.stack([40.0 + 30 * si, 36.0 + 30 * sj], 1)
    a, b = si <= 3, si >= 2
    lat, out = merge_lattices(
        Lattice(sq[a], np.stack([si[a], sj[a]], 1), np.zeros(a.sum(), bool)),
        sid[a],
        [(100.0, Lattice(sq[b], np.stack([si[b], sj[b]], 1), np.zeros(b.sum(), bool)), perm[sid[b]], 50.0)],
        square,
        cfg,
    )
    order = np.argsort(out)
    np.testing.assert_array_equal(out[order], sid)
    np.testing.assert_allclose(lat.xy[order], sq)


def test_join_lattices_joins_parts_of_one_lattice():
    """Two growths of one board in their own lattice frames (one turned by 90 deg and shifted)
    that overlap in two columns join into one lattice in the larger one's frame, every corner once
    at its own spot; parts whose shared corners need different turns, and a lattice far away,
    stay apart; a corner of the smaller part that its new neighbours do not predict is left out."""
    from cotrain.detect.grid_pass import join_lattices
    from cotrain.detect.lattice import Lattice

    cfg = GridConfig()
    ids = np.arange(NX * NY)
    i, j = ids % NX, ids // NX
    q = np.stack([40.0 + 30 * i + 0.5 * j * j, 36.0 + 30 * j + 0.3 * i * i], 1)  # a slightly bent grid
    left, right = i <= 5, i >= 4
    big = Lattice(q[left], np.stack([i[left], j[left]], 1), np.zeros(left.sum(), bool))
    turned = np.stack([j[right] + 7, -i[right] - 3], 1)  # (i, j) -> (j, -i), shifted
    small = Lattice(q[right], turned, np.zeros(right.sum(), bool))
    far = Lattice(q[left] + 1000.0, big.ab, big.filled)
    out = join_lattices([small, big, far], cfg)
    assert len(out) == 2 and out[1] is far
    joined = out[0]
    assert len(joined.ab) == NX * NY and len(joined.where) == NX * NY
    np.testing.assert_allclose(joined.xy[[joined.where[(a, b)] for a, b in zip(i, j)]], q)

    # The shared corners disagree about the turn: no join.
    scrambled = Lattice(q[right], turned[np.random.default_rng(0).permutation(len(turned))], small.filled)
    assert len(join_lattices([big, scrambled], cfg)) == 2

    # A corner of the smaller part off its lattice line (a wrong corner at its end) is left out.
    bad = q[right].copy()
    k_bad = np.nonzero((i[right] == NX - 1) & (j[right] == 2))[0][0]
    bad[k_bad] += [0.0, 16.0]  # over half a step off: 0.45 x 30 = 13.5 px
    joined = join_lattices([big, Lattice(bad, turned, small.filled)], cfg)[0]
    assert len(joined.ab) == NX * NY - 1 and (NX - 1, 2) not in joined.where


def test_join_lattices_refuses_the_next_row_of_a_thin_rhombus():
    """A board seen so obliquely that its cells are thin rhombi (sides 30 px, one diagonal 6.7 px):
    a corner of the smaller part that sits where its diagonal neighbour is (a row off) lies within
    0.45 of a step of its prediction, but nearer to a placed corner than that: it is left out, and
    every other corner joins."""
    from cotrain.detect.grid_pass import join_lattices
    from cotrain.detect.lattice import Lattice

    cfg = GridConfig()
    ids = np.arange(NX * NY)
    i, j = ids % NX, ids // NX
    q = np.stack([300.0 + 30 * i - 27 * j, 100.0 + 6 * j], 1)  # steps (30, 0) and (-27, 6)
    assert np.isclose(np.hypot(3, 6), min(np.hypot(*(q[a] - q[b])) for a in range(len(q)) for b in range(a)))
    left = i <= 5
    big = Lattice(q[left], np.stack([i[left], j[left]], 1), np.zeros(left.sum(), bool))
    right = (i >= 4) & ~((i == NX - 1) & (j == 3))  # the spot (NX - 1, 3) is not in the smaller part
    wrong = right & (i == NX - 2) & (j == 2)
    q_small = q[right].copy()
    q_small[wrong[right]] = q[(i == NX - 1) & (j == 3)][0]  # (NX - 2, 2) taken at its diagonal neighbour's spot
    assert np.hypot(*(q_small[wrong[right]][0] - q[wrong][0])) < cfg.match_radius * 30  # the step alone would let it in
    small = Lattice(q_small, np.stack([i[right], j[right]], 1), np.zeros(right.sum(), bool))
    joined = join_lattices([big, small], cfg)[0]
    assert (NX - 2, 2) not in joined.where
    assert len(joined.ab) == NX * NY - 2  # all the others, at their own spots
    for (a, b), k in joined.where.items():
        np.testing.assert_allclose(joined.xy[k], q[b * NX + a])


def test_merge_half_resolution_completes_an_empty_result_and_refuses_slips():
    """A flat board and a half-resolution result at the true corners (half their positions):
    where the full-resolution pass found nothing and the margin is sure, the corners are taken,
    fitted at full resolution, except one given its row neighbour's place (the other checker
    parity); an unsure margin keeps the empty result, and a full-resolution result with any
    corner is kept as it is (the half-resolution reading is for frames where nothing was found)."""
    from dataclasses import replace

    from cotrain.detect.grid_pass import GridResult, merge_half_resolution

    img, q = board_image(sq=40, org=(60, 50), size=(560, 400))
    cfg = GridConfig()
    ids = np.arange(NX * NY)
    at_half = (q + 0.5) / 2 - 0.5 + np.random.default_rng(0).normal(0, 0.1, q.shape)
    at_half[20] = at_half[21]  # corner 20 put on 21's place; 21 not reported
    keep = ids != 21
    half = GridResult(ids[keep], at_half[keep], np.ones(keep.sum()), 80.0)
    none = GridResult(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), float("nan"))
    out = merge_half_resolution(img, none, half, BOARD, cfg)
    assert set(out.ids.tolist()) == set(ids[keep].tolist()) - {20}
    assert np.linalg.norm(out.xy - q[out.ids], axis=1).max() < 0.1  # refitted at full resolution
    assert len(merge_half_resolution(img, none, replace(half, margin=20.0), BOARD, cfg).ids) == 0
    assert len(merge_half_resolution(img, none, replace(half, margin=30.0), BOARD, cfg).ids) == len(out.ids)
    for found in (GridResult(ids[:3], q[:3], np.ones(3), 40.0), GridResult(ids[:8], q[:8] + [3.0, 0.0], np.ones(8), 40.0)):
        assert merge_half_resolution(img, found, half, BOARD, cfg) is found


def test_completion_recovers_corners_the_growth_did_not_reach(monkeypatch):
    """A board at the side of a 200-degree lens whose lattices all stop halfway across the image
    (as a growth stopped by a bent row or a blurred stretch would leave them): with completion
    (GridConfig's shipped settings: the lens guessed from the image circle, edge rays always
    asked, a correlation of 0.7, 3 px from the rim) the grid pass reports most of the visible
    corners, each within 0.5 px of its label, those added with a confidence no higher than the
    placed ones'; without it, only the corners the lattices kept."""
    import cotrain.detect.grid_pass as gp
    from cotrain.detect.detector import Detector
    from cotrain.detect.lattice import Lattice
    from cotrain.targets import TargetConfig, make_target
    from tests.detect.test_tag_pass import centre, render

    g = make_target(TargetConfig(kind="checkerboard"))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "ds", 200, (c + [0.0, 0.0, -0.15]).tolist(), (c + [-0.5, 0.05, 0.0]).tolist())  # the print faces -z
    grow = gp.grow_lattice

    x_stop = np.median(q[vis, 0])

    def stopped(xy, *a, **k):  # every growth stops at the same place in the image (x_stop, crop pixels)
        lat = grow(xy, *a, **k)
        if lat is None:
            return None
        offset = xy_offset["x"]
        keep = lat.xy[:, 0] + offset < x_stop
        return Lattice(lat.xy[keep], lat.ab[keep], lat.filled[keep]) if keep.sum() >= 4 else None

    find = gp.find_candidates
    xy_offset = {"x": 0.0}

    def candidates(grey, roi, offset, *a, **k):
        xy_offset["x"] = float(offset[0])
        return find(grey, roi, offset, *a, **k)

    monkeypatch.setattr(gp, "grow_lattice", stopped)
    monkeypatch.setattr(gp, "find_candidates", candidates)
    cut = Detector(None, target=g, grid=GridConfig(completion=False)).detect(img)
    full = Detector(None, target=g).detect(img)
    assert 0 < len(cut.ids) <= 0.6 * vis.sum()
    assert vis[full.ids].all()
    err = np.linalg.norm(full.xy - q[full.ids], axis=1)
    assert err.max() < 0.5, f"corner {full.ids[err.argmax()]} is {err.max():.2f} px off"
    assert np.isin(np.nonzero(vis)[0], full.ids).mean() > 0.85
    added = ~np.isin(full.ids, cut.ids)
    assert added.sum() >= 10
    assert (full.confidence[added] <= full.confidence[~added].max() + 1e-9).all()  # the placement's, times the print's correlation


def test_half_resolution_pass_only_where_the_network_sees_a_board(monkeypatch):
    """A frame where the full-resolution pass finds nothing is read at half resolution too only
    where the network's board map covers GridConfig.half_min_board_share of its cells (the spy
    wraps the real grid pass and records the image sizes it ran on). There, corners nearer the
    rim than the half-resolution corners are reported are no evidence of the board's extent."""
    import cotrain.detect.detector as detector_module
    from cotrain.detect.detector import Detector

    seen = []
    real = detector_module.grid_pass

    def spy(grey, *args, **kwargs):
        seen.append((grey.shape, kwargs.get("extent_rim_px", 0.0)))
        return real(grey, *args, **kwargs)

    monkeypatch.setattr(detector_module, "grid_pass", spy)
    det = Detector()
    grey = np.full((720, 1280), 0.5, np.float32)  # nothing to find, big enough for the half pass
    box = det.letterbox(grey)
    h, w = det.input_size[0] // 4, det.input_size[1] // 4
    out = {
        "corner_prob": np.zeros((1, 1, h, w), np.float32),
        "col_logp": np.zeros((1, NX + 2, h, w), np.float32),
        "row_logp": np.zeros((1, NY + 2, h, w), np.float32),
    }
    share, rim = det.grid.half_min_board_share, det.grid.half_rim_px / 2  # the rim distance in half-resolution px
    for cells, runs in ((0, [((720, 1280), 0.0)]), (int(1.5 * share * h * w) + 1, [((720, 1280), 0.0), ((360, 640), rim)])):
        mask = np.zeros((h, w), np.float32)
        mask.ravel()[:cells] = 0.9
        seen.clear()
        assert len(det._grid(grey, box, {**out, "mask_prob": mask[None, None]}, det.grid).ids) == 0
        assert seen == runs


def test_extent_weight_is_zero_nearer_the_rim_than_the_limit():
    """Corners of a lattice inside an image circle of radius 100 px: those nearer its rim than
    ``rim_px`` weigh 0 as evidence of the board's extent, the others 1; a limit of 0 weighs all 1."""
    import cv2

    from cotrain.detect.grid_pass import extent_weight

    inside = np.zeros((240, 240), np.uint8)
    cv2.circle(inside, (120, 120), 100, 1, -1)
    rim_dist = cv2.distanceTransform(inside, cv2.DIST_L2, 3)
    depth = np.array([2.0, 5.0, 8.0, 30.0, 95.0])  # px inside the rim, along the x axis
    lat = Lattice(np.stack([220.0 - depth, np.full(5, 120.0)], 1), np.stack([np.arange(5), np.zeros(5, int)], 1), np.zeros(5, bool))
    np.testing.assert_allclose(rim_dist[120, (220 - depth).astype(int)], depth, rtol=0.05, atol=0.5)  # (a 3x3 mask: within 5 %)
    np.testing.assert_array_equal(extent_weight(lat, rim_dist, 6.0), [0, 0, 1, 1, 1])
    np.testing.assert_array_equal(extent_weight(lat, rim_dist, 0.0), np.ones(5))


def test_cache_keys_are_strict_json_and_tell_settings_apart():
    """The detectors' cache keys (written to a recording's bag.json) are strict JSON although a
    shipped limit is off (an infinite ``retry_min_margin``), and a limit set gives another key."""
    import json

    from cotrain.detect.detector import Detector
    from cotrain.targets import AprilGrid

    off = Detector().cache_key()
    on = Detector(grid=GridConfig(retry_min_margin=35.0)).cache_key()
    for key in (off, on, Detector(target=AprilGrid()).cache_key()):
        assert json.loads(json.dumps(key, allow_nan=False)) == key
    assert off["grid"]["retry_min_margin"] == "inf" and on != off


def test_a_lattice_stepped_across_the_margin_is_placed_again_cut_there():
    """A partial view, board columns 3-8 and every row, whose growth stepped across the board's
    right margin onto a distractor checker beside it (a bridge corner, then a 2 x 3 patch). Placed
    whole, the network's votes (0.5 for the right column and row against 0.05, at the view's
    corners) put the view right and the distractor off the board, but the geometry prefers a shift
    that puts the distractor on it: not sure, nothing reported. Cut at the right margin's line of
    evidence, the part on the board's side is the view itself, and it is placed surely, every id
    right, with the geometry behind it; a line whose evidence is too weak, or that cuts nothing,
    gives no part."""
    from cotrain.detect.grid_pass import cut_at_margins, placement_is_sure
    from cotrain.detect.identity import assign_ids

    cfg = GridConfig()
    view = [(i - 3, j) for j in range(NY) for i in range(3, NX)]  # lattice (a, b) = board (i - 3, j)
    right = NX - 4  # the view's last column
    distractor = [(right + 1, 2)] + [(a, b) for a in (right + 2, right + 3) for b in (1, 2, 3)]
    ab = np.array(view + distractor)
    lat = Lattice(ab * 30.0 + 100.0, ab, np.zeros(len(ab), bool))
    where = lat.where
    # Margin evidence: above the top row, below the bottom row, right of the last column (not at
    # the bridge's row: the growth went on there), and the distractor's own top, weak.
    edges = [(where[(a, 0)], 0, -1, 0.95) for a in range(right + 1)]
    edges += [(where[(a, NY - 1)], 0, 1, 0.95) for a in range(right + 1)]
    edges += [(where[(right, b)], 1, 0, 0.95) for b in range(NY) if b != 2]
    edges += [(where[(a, 1)], 0, -1, 0.2) for a in (right + 2, right + 3)]
    # Cell colours as printed (square (i, j) black when i + j is even), the distractor's likewise.
    dark = {}
    for a, b in where:
        if all(t in where for t in ((a + 1, b), (a, b + 1), (a + 1, b + 1))):
            dark[(a, b)] = 1.0 if (a + 3 + b) % 2 == 0 else -1.0
    lc, lr = np.full((len(ab), NX + 2), np.log(0.05)), np.full((len(ab), NY + 2), np.log(0.05))
    on = np.arange(len(view))
    lc[on, ab[on, 0] + 3 + 1] = lr[on, ab[on, 1] + 1] = np.log(0.5)
    whole = assign_ids(ab, lc, lr, dark, BOARD, cfg, edges)
    np.testing.assert_array_equal(whole.ids[len(view) :], -1)
    assert whole.geometry_margin < 0 and not placement_is_sure(whole.margin, whole.geometry_margin, cfg)

    parts = cut_at_margins(lat, edges, cfg)
    # The top and bottom lines cut nothing off; the distractor's top (0.4) is under cut_min_evidence.
    assert [sorted(map(tuple, p.ab.tolist())) for p in parts] == [sorted(view)]
    part = parts[0]
    np.testing.assert_array_equal(part.xy, part.ab * 30.0 + 100.0)
    part_edges = [(part.where[tuple(ab[k])], da, db, e) for k, da, db, e in edges if tuple(ab[k]) in part.where]
    part_dark = {c: v for c, v in dark.items() if c[0] < right}
    rows = [where[tuple(t)] for t in part.ab.tolist()]
    placed = assign_ids(part.ab, lc[rows], lr[rows], part_dark, BOARD, cfg, part_edges)
    np.testing.assert_array_equal(placed.ids, (part.ab[:, 0] + 3) + NX * part.ab[:, 1])
    assert placed.violated == 0 and placed.geometry_margin >= cfg.min_geometry_margin
    assert placement_is_sure(placed.margin, placed.geometry_margin, cfg)
    assert cut_at_margins(lat, edges, GridConfig(cut_min_evidence=5.0)) == []
    # The cut adds evidence: the same ids as the whole placed the view with, but the geometry now
    # behind them (cut_adds_evidence). Had only the margin moved, the part would not be taken.
    from cotrain.detect.grid_pass import cut_adds_evidence

    np.testing.assert_array_equal(whole.ids[rows], placed.ids)
    assert cut_adds_evidence(whole, True, lat, part, placed)
    no_news = placed._replace(margin=whole.margin + 0.4, geometry_margin=whole.geometry_margin)
    assert not cut_adds_evidence(whole, True, lat, part, no_news)
    assert cut_adds_evidence(whole, False, lat, part, no_news)  # the whole contradicted its margins: the cut answers that
    moved = no_news._replace(ids=np.where(placed.ids >= 0, placed.ids + 1, -1))  # other ids: another placement
    assert cut_adds_evidence(whole, True, lat, part, moved)
