"""Completion of a placed AprilGrid (cotrain.detect.print_model, verification, completion): local homographies, the check
against the print, and corners recovered from a few identified ones."""

from dataclasses import replace

import cv2
import numpy as np
import torch

from cotrain.detect.completion import best_option, complete_board, print_fit
from cotrain.detect.grid_config import GridConfig
from cotrain.detect.image_circle import EquidistantLens, PlaneMaps, fit_image_circle
from cotrain.detect.print_model import (
    CompletionConfig,
    each_local_map,
    local_homographies,
    local_homography,
    local_map,
    local_maps,
    map_through,
    print_correlation,
    smallest_step,
)
from cotrain.detect.saddle import outside_circle
from cotrain.detect.tag_candidates import tag_candidates
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_pass import tag_pass
from cotrain.detect.verification import neighbour_check, print_check, print_moved
from cotrain.targets import TargetConfig, make_target
from tests.detect.test_tag_pass import centre, render

GRID = GridConfig()  # the rim and crowding limits completion reads from the pass's grid settings


def test_local_homography_recovers_a_known_map_and_refuses_a_line():
    rng = np.random.default_rng(0)
    H = np.array([[900.0, 40.0, 300.0], [-30.0, 850.0, 200.0], [0.2, -0.1, 1.0]])
    P = rng.uniform(0, 0.3, (8, 2))
    h = np.c_[P, np.ones(8)] @ H.T
    q = h[:, :2] / h[:, 2:]
    H_fit = local_homography(P, q)
    assert np.allclose(H_fit / H_fit[2, 2], H / H[2, 2], rtol=1e-5)
    other = rng.uniform(-0.1, 0.4, (20, 2))  # extrapolated too
    h1, h2 = np.c_[other, np.ones(20)] @ H.T, np.c_[other, np.ones(20)] @ H_fit.T
    assert np.abs(h1[:, :2] / h1[:, 2:] - h2[:, :2] / h2[:, 2:]).max() < 1e-3
    line = np.stack([np.linspace(0, 0.3, 6), np.full(6, 0.1)], 1)
    assert local_homography(line, q[:6]) is None


def test_local_homographies_match_opencv_per_set_and_refuse_degenerate_sets():
    """The batched normalised DLT agrees with cv2.findHomography on each of 40 noisy point sets
    (projections of the fitted points within 0.02 px of OpenCV's), keeps the points in front,
    and refuses a set on one line and a set with every point the same."""
    rng = np.random.default_rng(1)
    N, K = 40, 7
    P = rng.uniform(0.0, 0.4, (N, K, 2))
    H_true = np.array([[900.0, 40.0, 300.0], [-30.0, 850.0, 200.0], [0.2, -0.1, 1.0]]) + rng.normal(0, 1, (N, 3, 3)) * [
        [40, 20, 30],
        [20, 40, 30],
        [0.1, 0.1, 0],
    ]
    h = np.concatenate([P, np.ones((N, K, 1))], 2) @ H_true.transpose(0, 2, 1)
    q = h[..., :2] / h[..., 2:] + rng.normal(0, 0.1, (N, K, 2))
    P[-3] = np.stack([np.linspace(0, 0.3, K), np.full(K, 0.1)], 1)  # one line along x
    P[-2] = np.stack([np.linspace(0, 0.3, K), np.linspace(0.05, 0.25, K)], 1)  # one diagonal line
    P[-1] = 0.2  # one point
    H, posed = local_homographies(P, q)
    assert posed[:-3].all() and not posed[-3:].any()
    four = np.array([[[0.0, 0.0], [0.1, 0.1], [0.2, 0.2], [0.3, 0.0]]])  # three of four on a line
    assert not local_homographies(four, four * 1000)[1][0]
    assert local_homographies(np.array([[[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1]]]), four * 1000)[1][0]
    for n in range(N - 3):
        H_cv, _ = cv2.findHomography(P[n], q[n], 0)
        a = np.c_[P[n], np.ones(K)] @ H[n].T
        b = np.c_[P[n], np.ones(K)] @ H_cv.T
        assert (a[:, 2] > 0).all()  # oriented: the points in front
        assert np.abs(a[:, :2] / a[:, 2:] - b[:, :2] / b[:, 2:]).max() < 0.02


def flat_view(board, H, size=(900, 700), blur=0.7):
    """The print seen through homography H (board metres -> pixels), point-sampled per pixel (no
    renderer involved), slightly blurred: float32 image in [0.1, 0.8]."""
    w, h = size
    Hinv = np.linalg.inv(H)
    pix = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 2)
    b = np.c_[pix, np.ones(len(pix))] @ Hinv.T
    xy = b[:, :2] / b[:, 2:]
    v = board.intensity(torch.from_numpy(xy))[0].numpy().reshape(h, w).astype(np.float32)
    return cv2.GaussianBlur(0.1 + 0.7 * v, (0, 0), blur)


def test_print_correlation_is_highest_for_the_corners_own_pattern():
    """Through the true homography every inner corner matches its own print far better than any
    grid neighbour's; moved by a gap onto the crossing square's next corner, the neighbour wins."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    H = np.array([[1000.0, 60.0, 120.0], [-40.0, -1000.0, 640.0], [0.15, 0.1, 1.0]])
    sm = flat_view(g, H)
    rim = np.full(sm.shape, 100.0, np.float32)
    cfg = CompletionConfig()
    P = g.points().numpy()[:, :2]
    for t in (26, 27, 38, 39, 64, 77, 90, 101):
        corr, other, _ = print_correlation(sm, rim, g, PlaneMaps(H[None]), np.zeros(2), t, cfg)
        assert corr > 0.85 and corr - other > 0.2, (t, corr, other)
    # Corner 27 (page column 3, row 2) and 28 (column 4) are the two sides of a crossing square.
    h = np.c_[P[[27, 28]], np.ones(2)] @ H.T
    q = h[:, :2] / h[:, 2:]
    corr, other, _ = print_correlation(sm, rim, g, PlaneMaps(H[None]), q[1] - q[0], 27, cfg)
    assert other > corr + 0.3


def test_a_candidate_where_the_board_meets_the_dark_beyond_the_rim_is_not_taken_for_the_corner():
    """Large tags (gaps of 50 px) seen flat, the image dark beyond a rim 10 px past corner 54.
    Where the corner's tag edge meets the rim (3.8 px inside it) the black, the white gap and the
    dark beyond make an X whose patch, cut by the rim as the corner's is, matches the print better
    than the corner does (about half of each patch is inside). Among the searched candidates the
    corner, whose edge rays follow the board's axes, goes before that X, whose rays do not.
    Counted as sure whatever its patch (``sure_inside`` 0), the X was chosen."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    t, scale, at = 54, 3000.0, np.array([300.0, 300.0])
    H = np.diag([scale, scale, 1.0])
    H[:2, 2] = at - scale * g.board_xy()[t]
    yy, xx = np.mgrid[0:600, 0:600]
    inside = xx < at[0] + 10.0  # the rim: a vertical line 10 px right of the corner
    img = np.where(inside, flat_view(g, H, size=(600, 600), blur=1.0), 0.02).astype(np.float32)
    rim = cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_L2, 3)
    sm = cv2.GaussianBlur(img, (0, 0), 1.0)
    to_image, gap = PlaneMaps(H[None]), smallest_step(g)
    x_junction = at + [10.0 - 3.8, 0.0]  # along the corner's edge towards +x, to the rim
    cfg = CompletionConfig()
    m_x, m_t = (print_correlation(sm, rim, g, to_image, q - at, t, cfg) for q in (x_junction, at))
    assert m_x.corr > m_t.corr > cfg.sure_corr and max(m_x.inside, m_t.inside) < cfg.sure_inside
    far = np.array([[0.0, 0.0]])  # no known corner near
    chosen = [
        best_option(
            sm,
            rim,
            g,
            to_image,
            at,
            t,
            g.board_xy()[t],
            gap,
            [x_junction, at],
            True,
            gap * scale,
            far,
            GRID.min_rim_px,
            GRID.crowd_radius,
            c,
        )[0]
        for c in (cfg, CompletionConfig(sure_inside=0.0))
    ]
    np.testing.assert_allclose(chosen[0], at)
    np.testing.assert_allclose(chosen[1], x_junction)


def _tilted_view():
    """Kalibr's 6 x 6 AprilGrid through a homography (tags about 50 px): the target, the blurred
    view, a rim distance that never binds, every corner's pixel (N, 2) and the inner corners' ids."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    H = np.array([[1000.0, 60.0, 120.0], [-40.0, -1000.0, 640.0], [0.15, 0.1, 1.0]])
    sm = flat_view(g, H)
    rim = np.full(sm.shape, 100.0, np.float32)
    P = g.points().numpy()[:, :2]
    h = np.c_[P, np.ones(len(P))] @ H.T
    c, r = np.arange(g.n_corners) % g.nx, np.arange(g.n_corners) // g.nx
    ids = np.nonzero((c > 0) & (c < g.nx - 1) & (r > 0) & (r < g.ny - 1))[0]
    return g, sm, rim, h[:, :2] / h[:, 2:], ids


def test_print_check_drops_a_corner_moved_across_its_gap_and_keeps_the_rest():
    """A flat view with every inner corner at its true place but two: one moved onto the other
    corner of its crossing square (as a lattice does where a gap of 2-3 px collapses), and one
    moved a whole tag side along its row. The check drops exactly those two."""
    g, sm, rim, q, ids = _tilted_view()
    xy = q[ids].copy()
    # Corner 27 (column 3) onto 28 (column 4: the crossing square's other side); corner 64
    # (column 4) onto 65 (column 5: the far end of its tag's side).
    xy[ids == 27] = q[28]
    xy[ids == 64] = q[65]
    ids_k, xy_k = ids[~np.isin(ids, [28, 65])], xy[~np.isin(ids, [28, 65])]
    keep = print_check(sm, rim, g, ids_k, xy_k, CompletionConfig())
    assert set(ids_k[~keep].tolist()) == {27, 64}
    # Too few corners to check: kept, unless strict (corners a second pass adds).
    few = ids_k[:4]
    assert print_check(sm, rim, g, few, q[few], CompletionConfig()).all()
    assert not print_check(sm, rim, g, few, q[few], CompletionConfig(), strict=np.ones(4, bool)).any()


def test_print_check_drops_a_large_tags_corner_whose_own_print_is_not_there():
    """In tags over 40 px the check allows a neighbour's print to match better by 0.35 (a local
    homography fits a large tag's bend less well). A corner moved 30 % along its tag's side, onto
    the tag's black border, matches no print (its own correlation under 0.1), a neighbour's a
    little better: dropped, where the margin alone kept it."""
    g, sm, rim, q, ids = _tilted_view()
    assert np.linalg.norm(q[27] - q[26]) > 40  # a tag side: large tags
    xy = q[ids].copy()
    xy[ids == 27] = q[27] + 0.3 * (q[26] - q[27])
    assert set(ids[~print_check(sm, rim, g, ids, xy, CompletionConfig())].tolist()) == {27}
    assert print_check(sm, rim, g, ids, xy, CompletionConfig(check_min_corr_large=-np.inf)).all()


def test_print_moved_finds_a_corner_slid_along_its_tags_side_that_the_print_check_keeps():
    """A corner slid 10-20 % of a 52 px tag side along it (5-10 px; as the growth slides where a
    tag's border runs into the board's rim) still matches its own print best, so the print check
    keeps it; where its neighbours put it the print matches better: print_moved finds it, and no
    other corner. Slid 2.6 px (under ``moved_px``), or with the test off, it is left alone."""
    g, sm, rim, q, ids = _tilted_view()
    cfg = CompletionConfig()
    assert not print_moved(sm, rim, g, ids, q[ids], cfg).any()
    for share in (0.1, 0.15, 0.2):
        xy = q[ids].copy()
        xy[ids == 27] = q[27] + share * (q[26] - q[27])
        assert print_check(sm, rim, g, ids, xy, cfg).all()
        assert ids[print_moved(sm, rim, g, ids, xy, cfg)].tolist() == [27]
        assert not print_moved(sm, rim, g, ids, xy, replace(cfg, moved_px=0.0)).any()
    xy = q[ids].copy()
    xy[ids == 27] = q[27] + 0.05 * (q[26] - q[27])
    assert np.linalg.norm(xy[ids == 27] - q[27]) < cfg.moved_px
    assert not print_moved(sm, rim, g, ids, xy, cfg).any()
    # Too few corners for a map: nothing is judged.
    few = ids[:4]
    assert not print_moved(sm, rim, g, few, q[few] + 8.0, cfg).any()


def test_half_resolution_adds_its_corners_but_not_one_its_neighbours_put_elsewhere():
    """A flat view read at both resolutions: the half-resolution reading adds the corners of one
    tag row that the full one missed (near their true places: each is fitted again at full
    resolution), except one of them slid 8 px along its tag's side (as a heavy blur makes the
    half-resolution growth do), which its own print still matches best, so the print check
    alone keeps it, but where its neighbours put it the print matches better (print_moved)."""
    from cotrain.detect.half_resolution import corners_at_half_resolution

    g, sm, rim, q, ids = _tilted_view()
    grey = sm.astype(np.float32)
    row = ids[(ids // g.nx) == 4]  # one row of inner corners: the half-resolution reading's own
    full = ids[~np.isin(ids, row)]
    half_xy = (q[row] + 0.5) / 2 - 0.5  # halve()'s pixels of the true places (the frame's sides are even)
    slid = row[3]
    along = (q[slid + 1] - q[slid]) / np.linalg.norm(q[slid + 1] - q[slid])
    half_xy[3] = (q[slid] + 8.0 * along + 0.5) / 2 - 0.5
    found = corners_at_half_resolution(grey, full, q[full], row, half_xy, g, GridConfig(), CompletionConfig())
    assert found is not None
    sel, xy = found
    assert set(row[sel].tolist()) == set(row.tolist()) - {int(slid)}
    assert np.abs(xy - q[row[sel]]).max() < 0.5  # fitted again at full resolution (the view is point-sampled)
    # Without print_moved the print check keeps the slid corner, 8 px off its place.
    found0 = corners_at_half_resolution(grey, full, q[full], row, half_xy, g, GridConfig(), CompletionConfig(moved_px=0.0))
    assert found0 is not None
    sel0, xy0 = found0
    assert int(slid) in row[sel0].tolist()
    assert np.linalg.norm(xy0[row[sel0].tolist().index(int(slid))] - q[slid]) > 7


def test_a_corner_put_back_after_print_moved_weighs_what_its_own_print_says():
    """A frame of the independent renderer (seed 5, FoV 220, frame 16) blurred 1.5 px more: the
    growth puts the corner of a decoded tag at the image circle's rim 9 px off (id 114).
    print_moved sets it aside; completion does not place it; it is put back, with its own
    print's correlation there (under 0.1) as its confidence, the calibrator's weight, where it
    had 0.99 or more. Every other corner lies within a pixel of its label with a confidence of 0.3 or more."""
    from calib_eval.detection.foreign import ForeignConfig, render_frame

    g = make_target(TargetConfig(kind="aprilgrid"))
    fr = render_frame(220, ForeignConfig(target="aprilgrid"), np.random.default_rng([5, 220, 16]), g)
    grey = cv2.GaussianBlur(fr.image, (0, 0), 1.5).astype(np.float32) / 255
    for complete, conf_114 in ((CompletionConfig(), (0.05, 0.1)), (CompletionConfig(moved_px=0.0), (0.99, 1.0))):
        r = tag_pass(grey, g, TagConfig(complete=complete))
        err = np.linalg.norm(r.xy - fr.corners[r.ids], axis=1)
        k = r.ids.tolist().index(114)
        assert 8 < err[k] < 10 and conf_114[0] <= r.confidence[k] <= conf_114[1]
        others = np.arange(len(r.ids)) != k
        assert others.sum() > 60 and err[others].max() < 1 and r.confidence[others].min() >= 0.3


def test_a_colour_cameras_sharpened_frame_gives_no_corner_off_its_place():
    """A frame of the independent renderer through a colour camera's processing (``--isp``: Bayer
    mosaic, white balance, demosaicing, an unsharp mask; seed 5, FoV 240, frame 13): the lattice
    grew two corners 13-19 px off into the squeezed tags at the board's far edge, whose own print
    correlates under 0.1 there. The print check drops them; no corner is reported off its place.
    Without that rule of the print check, print_moved sets them aside (they lie where their
    neighbours' maps do not put them) and completion places them; without both, they stay."""
    from calib_eval.detection.foreign import ForeignConfig, render_frame

    g = make_target(TargetConfig(kind="aprilgrid"))
    fr = render_frame(240, ForeignConfig(target="aprilgrid", isp=True), np.random.default_rng([5, 240, 13]), g)
    grey = fr.image.astype(np.float32) / 255
    no_rule = CompletionConfig(check_min_corr_large=-np.inf)
    for complete, wrong in ((CompletionConfig(), 0), (no_rule, 0), (replace(no_rule, moved_px=0.0), 2)):
        cfg = TagConfig(complete=complete)
        r = tag_pass(grey, g, cfg)
        err = np.linalg.norm(r.xy - fr.corners[r.ids], axis=1)
        assert len(r.ids) > 100 and int((err > 3).sum()) == wrong


def _anchor(g, block: list[int]) -> np.ndarray:
    """The corner ids of the tags in ``block``."""
    return np.unique(g.tag_corners(np.array(block)).ravel())


def test_complete_board_recovers_a_rim_view_from_four_tags():
    """A board seen 60-95 deg off-axis through a 200-degree Kannala-Brandt lens; given only the
    four tags of a 2 x 2 block at their labels, completion finds most other visible corners, each
    at its own label, and nothing outside the view."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, angle = render(g, "kb4", 200, (c + [0.0, 0.0, 0.28]).tolist(), (c + [-0.5, 0.05, 0.0]).tolist())
    grey = img.astype(np.float32) / 255
    allowed = ~outside_circle(grey)
    rim = cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)
    smoothed: dict[int, np.ndarray] = {}
    cand, _ = tag_candidates(grey, allowed, TagConfig(), smoothed, rim)
    given = _anchor(g, [14, 15, 20, 21])
    assert vis[given].all()
    ids, xy, corr, _ = complete_board(grey, smoothed, rim, cand, g, given, q[given], CompletionConfig(), GridConfig())
    added = ~np.isin(ids, given)
    assert vis[ids].all()
    err = np.linalg.norm(xy - q[ids], axis=1)
    assert err[added].max() < 0.5, f"corner {ids[added][err[added].argmax()]} is {err[added].max():.2f} px off"
    assert np.isnan(corr[~added]).all() and (corr[added] >= CompletionConfig().min_corr).all()
    found = np.isin(np.nonzero(vis)[0], ids).mean()
    assert found > 0.8, f"{found:.2f} of the visible corners"
    assert np.isin(np.nonzero(vis & (angle > 80))[0], ids).mean() > 0.6


def test_in_gaps_too_small_for_edge_rays_the_prints_match_decides():
    """Tags 8 px across seen flat (gaps of 2.4 px): a corner's edge rays would be read on a circle
    of 1.2 px, inside the blurred core of the X, where they do not follow the board's axes.
    There, a corner at its place is taken on its print's match, better than its grid neighbours'
    (by 0.6 and more here); with the rays required everywhere (``min_ray_px`` 0) it is refused. The other
    corner of its crossing square, a gap away, is refused either way: a neighbour's print
    matches it better."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    scale = 8.0 / g.cfg.tag_size
    H = np.array([[scale, 0.08 * scale, 30.0], [-0.05 * scale, scale, 25.0], [0.0, 0.0, 1.0]])
    sm = cv2.GaussianBlur(flat_view(g, H, size=(140, 130), blur=0.6), (0, 0), 1.0)
    rim = np.full(sm.shape, 100.0, np.float32)
    P = g.board_xy()
    h = np.c_[P, np.ones(len(P))] @ H.T
    q = h[:, :2] / h[:, 2:]
    gap = smallest_step(g)
    assert not CompletionConfig().reads_rays(gap * scale)
    far = np.array([[-100.0, -100.0]])  # no known corner near
    cases = ((CompletionConfig(), True), (CompletionConfig(min_ray_px=0.0), False))
    for t in (27, 38, 77):  # page columns 3, 2, 5: corner t + 1 is the other corner of its crossing square
        for cfg, taken in cases:
            args = (sm, rim, g, PlaneMaps(H[None]), q[t], t, P[t], gap)
            own = best_option(*args, [q[t]], False, gap * scale, far, GRID.min_rim_px, GRID.crowd_radius, cfg)[0]
            assert (own is not None) == taken, (t, cfg.min_ray_px)
            assert best_option(*args, [q[t + 1]], False, gap * scale, far, GRID.min_rim_px, GRID.crowd_radius, cfg)[0] is None


def test_completion_reaches_the_small_tags_of_a_grazing_view():
    """A board seen at a grazing angle through a 200-degree lens: its tags shrink from 30 px to
    under 8 px across the view. Completion reaches the far tags, whose gaps are too small for
    edge rays, on their prints' margin, in rounds after those that read rays: every corner found
    with the rays required everywhere is found at the same place, and at least 10 more (88 against
    74 here), each visible and within 0.6 px of its own label."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "kb4", 200, (c + [-0.7, 0.05, 0.25]).tolist(), (c + [0.2, 0.0, 0.0]).tolist())
    grey = img.astype(np.float32) / 255
    found = []
    for cfg in (TagConfig(), TagConfig(complete=CompletionConfig(min_ray_px=0.0))):
        r = tag_pass(grey, g, cfg)
        assert vis[r.ids].all()
        err = np.linalg.norm(r.xy - q[r.ids], axis=1)
        assert err.max() < 0.6, f"corner {r.ids[err.argmax()]} is {err.max():.2f} px off"
        found.append(dict(zip(r.ids.tolist(), r.xy)))
    assert len(found[0]) >= len(found[1]) + 10, (len(found[0]), len(found[1]))
    assert all(np.array_equal(found[0].get(i), p) for i, p in found[1].items())


def _rim_plane_through_lens(lens: EquidistantLens, n_sets: int, seed: int):
    """Board points (n_sets, 8, 2) in 2 x 4 blocks of a 3 cm grid and their exact pixels through
    ``lens``, for random poses that put them 60-110 deg off-axis."""
    rng = np.random.default_rng(seed)
    P = np.stack(np.meshgrid(np.arange(4) * 0.03, np.arange(2) * 0.03), -1).reshape(-1, 2)
    out_P, out_q = [], []
    while len(out_P) < n_sets:
        R = cv2.Rodrigues(rng.normal(size=3))[0]
        off = np.radians(rng.uniform(60, 110))
        az = rng.uniform(0, 2 * np.pi)
        t = 0.25 * np.array([np.sin(off) * np.cos(az), np.sin(off) * np.sin(az), np.cos(off)])
        p_cam = np.c_[P, np.zeros(len(P))] @ R.T + t
        if (p_cam @ t / np.linalg.norm(t) / np.linalg.norm(p_cam, axis=1) < 0.99).any():
            continue  # keep the block small in the view
        v = p_cam / np.linalg.norm(p_cam, axis=1, keepdims=True)
        out_P.append(P)
        out_q.append(lens.project(v))
    return np.array(out_P), np.array(out_q)


def test_local_maps_through_the_lens_predict_a_plane_exactly_where_pixel_homographies_bend():
    """Seven corners of a block of board points 60-110 deg off-axis through an equidistant lens:
    the map through the lens's rays predicts the eighth to a millionth of a pixel (a plane's
    points map to rays by a homography), the pixel homography misses it by tenths of a pixel, up to
    pixels; one map and the batch agree."""
    lens = EquidistantLens((640.0, 360.0), 380.0 / np.radians(100))
    P, q = _rim_plane_through_lens(lens, 20, 0)
    maps, posed = local_maps(P[:, :7], q[:, :7], lens)
    assert posed.all()
    err_lens = np.linalg.norm(maps(P[:, 7:])[:, 0] - q[:, 7], axis=1)
    assert err_lens.max() < 1e-6
    pixel, posed = local_maps(P[:, :7], q[:, :7])
    err_pixel = np.linalg.norm(pixel(P[:, 7:])[:, 0] - q[:, 7], axis=1)
    assert np.median(err_pixel) > 0.1 and err_pixel.max() > 1.0
    one = local_map(P[0, :7], q[0, :7], lens)
    np.testing.assert_allclose(one(P[:1, 7:]), q[:1, 7:], atol=1e-6)
    np.testing.assert_allclose(maps.take(3)(P[3:4]), q[3:4], atol=1e-6)


def test_each_local_map_is_local_map_set_by_set():
    """Completion's maps of many point sets at once are, bit for bit, the maps of one set at a
    time (:func:`local_map`), through the lens and in pixels; a set on one line (no map), and one
    that spans more of the lens's sphere than one view holds, are marked and do not disturb the
    others."""
    lens = EquidistantLens((640.0, 360.0), 380.0 / np.radians(100))
    P, q = _rim_plane_through_lens(lens, 12, 1)
    P[5] = np.c_[np.arange(8) * 0.03, np.zeros(8)]  # every point on one board line: no homography
    # Six of a set's points 100 deg off-axis to one side, two to the other: no one view holds them.
    off = np.radians(100.0)
    az = np.radians([-8.0, -4.0, 0.0, 4.0, 8.0, 12.0, 176.0, 184.0])
    el = np.array([0.0, 0.05, -0.05, 0.0, 0.05, -0.05, 0.0, 0.05])
    q[8] = lens.project(np.stack([np.sin(off) * np.cos(az), np.sin(off) * np.sin(az) + el, np.full(8, np.cos(off))], 1))
    pts = P[:, :3] + 0.01
    for with_lens in (lens, None):
        maps, posed = each_local_map(P, q, with_lens)
        none = {5, 8} if with_lens is not None else {5}
        assert posed.tolist() == [n not in none for n in range(12)]
        got = maps(pts)
        for n in range(12):
            one = local_map(P[n], q[n], with_lens)
            if n in none:
                assert one is None
                continue
            np.testing.assert_array_equal(maps.take(n).H, one.H)
            np.testing.assert_array_equal(got[n], one(pts[n][None])[0])


def _circle_view(grey: np.ndarray):
    """What the tag pass sets up for a fisheye frame ``grey``: the lens guessed from its image
    circle (TagConfig's FoV, 210 deg), the distance to the rim, the blur cache and the candidates."""
    outside = outside_circle(grey)
    lens = EquidistantLens.from_circle(*fit_image_circle(outside), GridConfig().lens_fov)
    rim = cv2.distanceTransform((~outside).astype(np.uint8), cv2.DIST_L2, 3)
    smoothed: dict[int, np.ndarray] = {}
    cand, _ = tag_candidates(grey, ~outside, TagConfig(), smoothed, rim)
    return lens, rim, smoothed, cand


def _completed_close_view(model: str, fov: float, z: float, block: list[int], runs: dict) -> dict:
    """A board ``z`` m from a ``model`` lens of ``fov`` deg, looking half a metre aside (a rim
    view of large bent tags), completed from the tags of ``block`` at their labels under each
    ``runs`` entry (name -> ``"lens"`` (guessed from the image circle, 210 deg) or None (pixel
    homographies), and a CompletionConfig): every corner found is visible and within 0.5 px of its
    label. Returns how many corners each adds."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, model, fov, (c + [0.0, 0.0, z]).tolist(), (c + [-0.5, 0.05, 0.0]).tolist())
    grey = img.astype(np.float32) / 255
    lens, rim, smoothed, cand = _circle_view(grey)
    given = _anchor(g, block)
    assert vis[given].all()
    found = {}
    for name, (through, cfg) in runs.items():
        ids, xy, _, _ = complete_board(
            grey, smoothed, rim, cand, g, given, q[given], cfg, GridConfig(), lens if through == "lens" else None
        )
        assert vis[ids].all()
        err = np.linalg.norm(xy - q[ids], axis=1)
        assert err.max() < 0.5, f"{name}: corner {ids[err.argmax()]} is {err.max():.2f} px off"
        found[name] = len(ids) - len(given)
    return found


def test_complete_board_through_the_lens_recovers_more_of_a_close_rim_view():
    """A board 8 cm from a 200-degree Kannala-Brandt lens, 40-90 deg off-axis (tags 30-110 px,
    bent), given the four tags of a 2 x 2 block: through the lens guessed from the image circle
    (210 deg) completion finds more of the visible corners than through pixel homographies, each
    at its own label (69 against 66; 63 while a prediction's map had to fit its neighbours within
    half a gap, until 2026-12-08: the pixel homographies' misfit at the rim refused predictions)."""
    runs = {"lens": ("lens", CompletionConfig()), "pixels": (None, CompletionConfig())}
    found = _completed_close_view("kb4", 200, 0.08, [13, 14, 19, 20], runs)
    assert found["lens"] > found["pixels"], found


def test_map_through_a_point_fits_it_exactly_and_refuses_one_off_the_plane():
    """The map through four points of a known homography and a fifth on it reproduces all five;
    with the fifth moved off the plane by more than the limit it is refused, within it kept."""
    H = np.array([[900.0, 40.0, 300.0], [-30.0, 950.0, 200.0], [0.2, -0.1, 1.0]])
    P = np.array([[0.0, 0.0], [0.1, 0.0], [0.1, 0.1], [0.0, 0.1], [0.05, 0.12]])
    h = np.c_[P, np.ones(len(P))] @ H.T
    q = h[:, :2] / h[:, 2:]
    m = map_through(P[:4], q[:4], P[4], q[4], None, 0.01)
    np.testing.assert_allclose(m(P[None])[0], q, atol=1e-6)
    assert map_through(P[:4], q[:4], P[4], q[4] + [6.0, 0.0], None, 1.0) is None
    assert map_through(P[:4], q[:4], P[4], q[4] + [6.0, 0.0], None, 5.0) is not None


def test_complete_board_judges_a_bent_corner_again_under_the_map_through_it():
    """A board 12 cm from a 240-degree unified-model lens, 25-115 deg off-axis, completed from
    the four tags of a 2 x 2 block through pixel homographies (a frame whose lens is unknown): the
    homography from a corner's neighbours misses the bend of the large tags toward the rim, so
    their print fails there. Judged again under the map through each candidate (refit_gap_px),
    completion finds more of the visible corners, each at its own label."""
    runs = {"refit": (None, CompletionConfig()), "no refit": (None, CompletionConfig(refit_gap_px=0.0))}
    found = _completed_close_view("ucm", 240, 0.12, [14, 15, 20, 21], runs)
    assert found["refit"] >= found["no refit"] + 10, found


def test_complete_board_adds_nothing_where_the_board_is_covered():
    """A flat view (point-sampled print, no renderer) with half the board under a grey sheet:
    corners under it are not added, those in view are, and none are off their labels."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    H = np.array([[1000.0, 60.0, 120.0], [-40.0, -1000.0, 640.0], [0.15, 0.1, 1.0]])
    grey = flat_view(g, H)
    P = g.points().numpy()[:, :2]
    h = np.c_[P, np.ones(len(P))] @ H.T
    q = h[:, :2] / h[:, 2:]
    x_cut = np.median(q[:, 0])
    grey[:, int(x_cut) :] = 0.5  # the sheet
    rim = np.full(grey.shape, 100.0, np.float32)
    smoothed: dict[int, np.ndarray] = {}
    cand, _ = tag_candidates(grey, np.ones(grey.shape, bool), TagConfig(), smoothed, rim)
    given = _anchor(g, [0, 1, 6, 7])
    ids, xy, _, _ = complete_board(grey, smoothed, rim, cand, g, given, q[given], CompletionConfig(), GridConfig())
    in_view = q[:, 0] < x_cut - 8
    assert np.isin(np.nonzero(in_view)[0], ids).mean() > 0.9
    assert (q[ids, 0] < x_cut + 1).all(), "a corner under the sheet was added"
    err = np.linalg.norm(xy - q[ids], axis=1)
    assert err.max() < 1.0 and err[in_view[ids]].max() < 0.4  # beside the sheet's edge the junction is cut


def test_the_tag_pass_completes_rim_views():
    """Two 220-degree views (Double Sphere, UCM), the board up to 109 deg off-axis: the tag pass
    with completion reports every corner it reports without and the few the growth missed, all
    at their own labels."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    for model, z in (("ds", 0.28), ("ucm", 0.2)):
        img, q, vis, _ = render(g, model, 220, (c + [0.0, 0.0, z]).tolist(), (c + [-0.6, 0.4, 0.0]).tolist())
        grey = img.astype(np.float32) / 255
        grown = tag_pass(grey, g, TagConfig(complete=CompletionConfig(rounds=0)))
        full = tag_pass(grey, g, TagConfig())
        assert set(grown.ids.tolist()) < set(full.ids.tolist())
        assert vis[full.ids].all() and np.isin(np.nonzero(vis)[0], full.ids).mean() > 0.98
        assert np.linalg.norm(full.xy - q[full.ids], axis=1).max() < 0.5


def test_complete_board_recovers_a_checkerboard_rim_view_from_a_block_of_corners():
    """The same completion on a checkerboard (its step is the square, its print the checker):
    a 9 x 6 board seen 30-100 deg off-axis through a 200-degree lens, given a 3 x 3 block of its
    corners at their labels, finds most visible corners through the lens guessed from the image
    circle, each at its own label (the print's parity refuses the neighbouring squares' corners)."""
    g = make_target(TargetConfig(kind="checkerboard", squares_x=10, squares_y=7, square_size=0.04, margin=0.5))
    c = np.array(centre(g))
    img, q, vis, angle = render(g, "ds", 200, (c + [0.0, 0.0, -0.2]).tolist(), (c + [-0.5, 0.05, 0.0]).tolist())  # the print faces -z
    grey = img.astype(np.float32) / 255
    lens, rim, smoothed, cand = _circle_view(grey)
    i, j = np.meshgrid(np.arange(3, 6), np.arange(2, 5))
    given = (j * g.nx + i).ravel()
    assert vis[given].all() and vis.sum() > 35 and angle[vis].max() > 95
    ids, xy, corr, _ = complete_board(grey, smoothed, rim, cand, g, given, q[given], CompletionConfig(check=False), GridConfig(), lens)
    assert vis[ids].all()
    err = np.linalg.norm(xy - q[ids], axis=1)
    assert err.max() < 0.5, f"corner {ids[err.argmax()]} is {err.max():.2f} px off"
    found = np.isin(np.nonzero(vis)[0], ids).mean()
    assert found > 0.8, f"{found:.2f} of the visible corners"


def _completed_small_tags(blur: float, cfgs: list[CompletionConfig], tol: float) -> list[int]:
    """Tags of 8-14 px seen 60-90 deg off-axis through a 200-degree UCM lens, blurred by ``blur``
    px, completed from the four tags of one block under each of ``cfgs``: every corner found is
    visible and within ``tol`` px of its label; returns how many each finds."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "ucm", 200, (c + [0.0, 0.0, 1.0]).tolist(), (c + [-0.3, 0.05, 0.0]).tolist())
    grey = cv2.GaussianBlur(img.astype(np.float32) / 255, (0, 0), blur)
    lens, rim, smoothed, cand = _circle_view(grey)
    given = _anchor(g, [14, 15, 20, 21])
    found = []
    for cfg in cfgs:
        ids, xy, _, _ = complete_board(grey, dict(smoothed), rim, cand, g, given, q[given], cfg, GridConfig(), lens)
        assert vis[ids].all()
        err = np.linalg.norm(xy - q[ids], axis=1)
        assert err.max() < tol, f"corner {ids[err.argmax()]} is {err.max():.2f} px off"
        found.append(len(ids))
    return found


def test_complete_board_fits_small_gaps_with_a_looser_symmetry():
    """Tags of about 9 px (gaps of under 3 px) blurred by 0.8 px: at the smallest window the
    crossing square's far corner breaks the point symmetry, and a fit held to the candidates'
    symmetry fails at many corners; tried again with ``small_min_symmetry`` where the local gap is
    under ``small_gap_px``, completion from four tags finds at least 10 more, each within 1 px of
    its label."""
    found = _completed_small_tags(0.8, [CompletionConfig(small_gap_px=x, print_fit_gap_px=0.0) for x in (0.0, 4.0)], tol=1.0)
    assert found[1] >= found[0] + 10, found


def test_complete_board_reports_the_corners_it_predicted_in_view_and_found_nothing_at():
    """A view crossing the image circle of a 200-degree lens (a fifth of the board beyond it):
    the tag pass finds the visible corners and reports as unfound exactly those it missed, none
    of the corners beyond the circle. One tag's area painted over: completion reports its corners
    unfound, and only corners in view. From one block of four tags with two rounds only, the
    corners not yet tried count as unfound; with enough rounds every visible corner is found and
    none is."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "kb4", 200, (c + [0.0, 0.0, 0.28]).tolist(), (c + [-0.9, 0.05, 0.0]).tolist())
    assert (~vis).sum() >= 15
    det = tag_pass(img.astype(np.float32) / 255, g)
    missed = set(np.nonzero(vis)[0]) - set(det.ids.tolist())
    assert len(missed) <= 0.05 * vis.sum()
    assert det.unfound == len(missed)
    grey = img.astype(np.float32) / 255
    outside = outside_circle(grey)
    allowed = ~outside
    rim = cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)
    circle = fit_image_circle(outside)
    assert circle is not None
    lens = EquidistantLens.from_circle(*circle, 210.0)
    smoothed: dict[int, np.ndarray] = {}
    cand, _ = tag_candidates(grey, allowed, TagConfig(), smoothed, rim)
    block = _anchor(g, [14, 15, 20, 21])
    few = complete_board(grey, smoothed, rim, cand, g, block, q[block], CompletionConfig(rounds=2), GridConfig(), lens)
    assert len(few.unfound) >= 10 and not np.isin(few.unfound, few.ids).any()
    full = complete_board(grey, smoothed, rim, cand, g, block, q[block], CompletionConfig(rounds=30), GridConfig(), lens)
    assert set(full.ids.tolist()) == set(np.nonzero(vis)[0].tolist()) and not len(full.unfound)
    # Tag 21's area painted grey: its corners are predicted in view and found nowhere.
    inner = g.tag_corners(np.array([21]))[0]
    assert vis[inner].all() and np.isin(inner, det.ids).all()
    x, y, w, h = cv2.boundingRect(np.rint(q[inner]).astype(np.int32))
    painted = img.copy()
    painted[y - 2 : y + h + 3, x - 2 : x + w + 3] = 128
    grey = painted.astype(np.float32) / 255
    smoothed = {}
    cand, _ = tag_candidates(grey, allowed, TagConfig(), smoothed, rim)
    keep = ~np.isin(det.ids, inner)
    ids, _, _, unfound = complete_board(grey, smoothed, rim, cand, g, det.ids[keep], det.xy[keep], CompletionConfig(), GridConfig(), lens)
    assert not np.isin(inner, ids).any()
    assert set(inner.tolist()) <= set(unfound.tolist())
    assert vis[unfound].all(), "a corner beyond the image circle is reported unfound"


def test_rays_along_reads_a_corner_next_to_the_image_border_on_a_smaller_circle():
    """An X-junction of 40 px squares 6 px below the image's top edge: its rays are read on a
    circle that fits inside the image (the 20 px circle its gap asks for would leave it, and gave
    no rays), and they follow the board's axes; a circle that would have to shrink under
    MIN_BORDER_RAY_PX (2 px from the edge) still gives none. The same corner turned by 45 deg
    against the board's axes fails."""
    from cotrain.detect.print_model import MIN_BORDER_RAY_PX, CompletionConfig, rays_along

    def checker(x0: float, y0: float, turn_deg: float = 0.0) -> np.ndarray:
        yy, xx = np.mgrid[0:120, 0:200].astype(np.float64)
        t = np.radians(turn_deg)
        u = np.cos(t) * (xx - x0) + np.sin(t) * (yy - y0)
        v = -np.sin(t) * (xx - x0) + np.cos(t) * (yy - y0)
        img = np.where((np.floor(u / 40) + np.floor(v / 40)) % 2 == 0, 0.8, 0.1).astype(np.float32)
        return cv2.GaussianBlur(img, (0, 0), 0.7)

    to_image = PlaneMaps(np.array([[[1.0, 0, 0], [0, 1, 0], [0, 0, 1]]]))  # board millimetres = pixels
    cfg = CompletionConfig()
    gap = 40.0
    assert cfg.ray_radius * gap > 6  # the circle the gap asks for leaves the image
    q = np.array([100.0, 6.0])
    assert rays_along(checker(*q), q, to_image, q, gap, gap, cfg)
    assert not rays_along(checker(*q, turn_deg=45), q, to_image, q, gap, gap, cfg)
    q2 = np.array([100.0, 1.0 + MIN_BORDER_RAY_PX - 1.0])
    assert not rays_along(checker(*q2), q2, to_image, q2, gap, gap, cfg)


def _board_72_deg_off_axis():
    """A 10 x 7 checkerboard whose plane's centre lies 0.3 m away, 72 deg off the axis, turned 30
    deg toward the camera, through an equidistant lens of 220 degrees: the board, the lens and
    every corner's pixel position (54, 2)."""
    board = make_target(TargetConfig(kind="checkerboard", squares_x=10, squares_y=7, square_size=0.04))
    lens = EquidistantLens((640.0, 360.0), 340.0 / np.radians(110))
    P = board.board_xy()
    off, turn = np.radians(72), np.radians(30)
    c = 0.3 * np.array([np.sin(off), 0.0, np.cos(off)])
    ex = np.array([np.cos(off + turn), 0.0, -np.sin(off + turn)])
    ey = np.array([0.0, 1.0, 0.0])
    X = c + (P[:, :1] - P[:, 0].mean()) * ex + (P[:, 1:] - P[:, 1].mean()) * ey
    return board, lens, lens.project(X)


def test_neighbour_check_drops_a_corner_off_where_its_neighbours_put_it():
    """A 10 x 7 checkerboard about 72 deg off-axis through an equidistant lens of 220 degrees (squares
    bent and foreshortened): with the lens, every exact corner fits its neighbours' map and is kept;
    a corner moved by 0.3 of its square (a T-junction at an occluder's edge) is dropped, and its
    neighbours, whose maps it bends, are kept by the second pass; one moved by 0.1 stays. Without
    the lens the bend alone puts many corners off by more than the pixel maps can follow, and
    where more than ``max_share`` would be dropped, none is."""
    board, lens, q = _board_72_deg_off_axis()
    ids = np.arange(board.n_corners)
    assert neighbour_check(board, ids, q, 7, 0.2, lens).all()
    square = np.linalg.norm(q[23] - q[22])
    moved = q.copy()
    moved[22] += np.array([0.3 * square, 0.0])
    keep = neighbour_check(board, ids, moved, 7, 0.2, lens)
    assert not keep[22] and keep.sum() == board.n_corners - 1
    moved[22] = q[22] + np.array([0.1 * square, 0.0])
    assert neighbour_check(board, ids, moved, 7, 0.2, lens).all()
    # Without the lens the bend alone puts many corners off by more than the pixel maps follow:
    # where more than max_share would go, the maps are at fault and every corner is kept.
    assert np.mean(~neighbour_check(board, ids, q, 7, 0.02, None)) > 0.2
    assert neighbour_check(board, ids, q, 7, 0.02, None, max_share=0.2).all()
    moved[22] = q[22] + np.array([0.3 * square, 0.0])
    assert neighbour_check(board, ids, moved, 7, 0.2, lens, max_share=0.2).sum() == board.n_corners - 1


def test_neighbour_check_drops_the_worst_corner_where_it_bends_a_neighbour():
    """The board of the test above, seen only in a lattice of 2 x 4 corners (a strip at the rim):
    each corner's map is made of few others, so a corner moved by 0.21 of its square bends its
    neighbours' maps, and it and a neighbour both miss by about the threshold. The two passes
    keep it; the worst-first rounds drop it, because without it that neighbour misses by less
    than half as much, and keep the other seven. The exact corners are all kept, and so is a
    corner 0.17 off among the whole board's, whose neighbours it does not bend."""
    board, lens, q_all = _board_72_deg_off_axis()
    ids = np.array([r * board.nx + k for r in range(2) for k in range(4)])
    q = q_all[ids]
    assert neighbour_check(board, ids, q, 7, 0.2, lens, 0.2, 0.15, 3).all()
    moved = q.copy()
    moved[5] += 0.21 * np.linalg.norm(q[1] - q[0]) * np.array([np.cos(np.radians(30)), np.sin(np.radians(30))])
    assert neighbour_check(board, ids, moved, 7, 0.2, lens, 0.2).all()
    keep = neighbour_check(board, ids, moved, 7, 0.2, lens, 0.2, 0.15, 3)
    assert not keep[5] and keep.sum() == len(ids) - 1
    # On the whole board a corner 0.17 of a square off bends no neighbour that far: it stays (a
    # corner the lens guess fits less well is not dropped for missing by a little).
    square = np.linalg.norm(q_all[23] - q_all[22])
    moved_all = q_all.copy()
    moved_all[22] += np.array([0.17 * square, 0.0])
    assert neighbour_check(board, np.arange(board.n_corners), moved_all, 7, 0.2, lens, 0.2, 0.15, 3).all()


def _sensor_view(g, H: np.ndarray, size: tuple[int, int], blur: float) -> np.ndarray:
    """The print of target ``g`` seen through the homography ``H`` (board metres -> pixels) in an
    image of ``size`` (W, H), integrated over each pixel (4 x 4 point samples) as a sensor does and
    blurred by ``blur`` px: black 0.1, white 0.8."""
    k = 4
    up = np.diag([k, k, 1.0]) @ np.array([[1.0, 0, 0.5], [0, 1, 0.5], [0, 0, 1]]) @ H  # pixel centres at (i + 0.5) / k - 0.5
    fine = flat_view(g, np.array([[1.0, 0, -0.5], [0, 1, -0.5], [0, 0, 1]]) @ up, size=(size[0] * k, size[1] * k), blur=1e-3)
    return cv2.GaussianBlur(cv2.resize(fine, size, interpolation=cv2.INTER_AREA), (0, 0), blur)


def _grey_print(H: np.ndarray, size: tuple[int, int], blur: float, noise: float, streak: int = 1):
    """A grey print (black 0.35, white 0.75) of the default AprilGrid seen through homography
    ``H`` in an image of ``size``, blurred by ``blur`` px (and along x over ``streak`` px), with
    noise of ``noise`` (no renderer involved). Returns the board, the image, a rim map that never
    cuts, every corner's pixel (N, 2), the inner corners' ids and their local gaps (px)."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    rng = np.random.default_rng(3)
    v = cv2.filter2D(_sensor_view(g, H, size, blur), -1, np.full((1, streak), 1 / streak, np.float32))
    img = (0.35 + (v - 0.1) / 0.7 * 0.4 + rng.normal(0, noise, v.shape)).astype(np.float32)
    rim = np.full(img.shape, 100.0, np.float32)
    to_image = PlaneMaps(H[None])
    P = g.points().numpy()[:, :2]
    q = to_image(P[None])[0]
    c, r = np.arange(g.n_corners) % g.nx, np.arange(g.n_corners) // g.nx
    inner = np.nonzero((c > 0) & (c < g.nx - 1) & (r > 0) & (r < g.ny - 1))[0]
    gaps = np.linalg.norm(to_image((P[inner] + [g.gap, 0])[None])[0] - q[inner], axis=1)
    return g, img, rim, q, inner, gaps


def _print_fit_errors(g, img, rim, H, q, inner, gaps, off_px: float, cfg: CompletionConfig) -> np.ndarray:
    """print_fit at every inner corner from a prediction ``off_px`` away in a direction that
    varies by corner (the map H moved by that much): the distances to the corners (NaN where it
    finds nothing)."""
    errs = []
    for t, gap_px in zip(inner, gaps):
        off = off_px * np.array([np.cos(t), np.sin(t)])
        moved = PlaneMaps((np.array([[1.0, 0, off[0]], [0, 1, off[1]], [0, 0, 1]]) @ H)[None])  # predicts q[t] + off
        found = print_fit(img, rim, g, moved, t, gap_px, cfg)
        errs.append(np.nan if found is None else np.linalg.norm(found - q[t]))
    return np.array(errs)


_SMALL_GAPS = np.array([[240.0, 20.0, 200.0], [-15.0, -230.0, 300.0], [0.1, 0.05, 1.0]])  # gaps of 3-5.5 px in 420 x 360


def test_print_fit_finds_corners_in_gaps_of_a_few_pixels():
    """A grey print seen through a homography with gaps of 3-5.5 px (tags of 10-18 px), blurred
    by 1.2 px, with noise: from predictions 1.5 px off in any direction (maps moved by that much),
    the print moved onto the image lands within 0.1 px of each inner corner (0.05 on median). On
    a flat patch, and from a prediction farther off than ``search`` of the gap, it finds nothing."""
    g, img, rim, q, inner, gaps = _grey_print(_SMALL_GAPS, (420, 360), 1.2, 0.01)
    assert 3.0 < gaps.min() and gaps.max() < 5.5
    cfg = CompletionConfig()
    errs = _print_fit_errors(g, img, rim, _SMALL_GAPS, q, inner, gaps, 1.5, cfg)
    assert errs.max() < 0.1 and np.median(errs) < 0.05, (errs.max(), np.median(errs))  # NaN (not found) fails too
    flat = np.full_like(img, 0.5) + np.random.default_rng(4).normal(0, 0.01, img.shape).astype(np.float32)
    assert print_fit(flat, rim, g, PlaneMaps(_SMALL_GAPS[None]), inner[0], gaps[0], cfg) is None
    far = PlaneMaps((np.array([[1.0, 0, 1.2 * cfg.search * gaps[5]], [0, 1, 0], [0, 0, 1]]) @ _SMALL_GAPS)[None])
    assert print_fit(img, rim, g, far, inner[5], gaps[5], cfg) is None


def test_print_fit_holds_in_gaps_up_to_its_limit_under_a_blur_along_one_axis():
    """Gaps of 7-9 px, up to ``print_fit_gap_px`` (10), where the saddle fits failing on rendered
    frames were still the print fit's to take (at the rim, under motion blur): the grey print
    blurred by 1.5 px and along x over 7 px, with noise, from predictions 1 px off. The print moved
    onto the image lands within 0.2 px of every inner corner (0.05 on median)."""
    H = np.array([[552.0, 46.0, 172.5], [-34.5, -529.0, 644.0], [0.1, 0.05, 1.0]])
    g, img, rim, q, inner, gaps = _grey_print(H, (800, 720), 1.5, 0.01, streak=7)
    assert 7.0 < gaps.min() and gaps.max() < CompletionConfig().print_fit_gap_px
    errs = _print_fit_errors(g, img, rim, H, q, inner, gaps, 1.0, CompletionConfig())
    assert errs.max() < 0.2 and np.median(errs) < 0.05, (errs.max(), np.median(errs))


def test_print_fit_holds_under_noise_of_a_tenth_of_the_contrast():
    """The grey print of gaps of 3-5.5 px under noise of a tenth of its contrast (0.04 against
    0.4), as a dim or under-exposed frame gives: the print moved onto the image explains the
    share asked through the lens (``print_fit_min_r2``, 0.7; this flat view's map is a pixel
    homography, whose own bar is set to it here) at every inner corner and lands within 0.25 px of
    each (0.12 on median); the pixel homographies' bar (0.8, kept for the bend they miss at the
    rim) refuses a third of them. On a flat patch with that noise it finds nothing."""
    g, img, rim, q, inner, gaps = _grey_print(_SMALL_GAPS, (420, 360), 1.2, 0.04)
    cfg = CompletionConfig(print_fit_min_r2_pixels=CompletionConfig().print_fit_min_r2)
    errs = _print_fit_errors(g, img, rim, _SMALL_GAPS, q, inner, gaps, 1.5, cfg)
    assert errs.max() < 0.25 and np.median(errs) < 0.15, (errs.max(), np.median(errs))
    strict = _print_fit_errors(g, img, rim, _SMALL_GAPS, q, inner, gaps, 1.5, CompletionConfig())
    assert np.isfinite(strict).sum() < 0.75 * len(inner), np.isfinite(strict).sum()
    flat = np.full_like(img, 0.5) + np.random.default_rng(4).normal(0, 0.04, img.shape).astype(np.float32)
    assert all(print_fit(flat, rim, g, PlaneMaps(_SMALL_GAPS[None]), t, gap_px, cfg) is None for t, gap_px in zip(inner[:40], gaps[:40]))


def test_complete_board_finds_the_corners_a_glare_leaves_faint_and_keeps_the_rest_where_they_were():
    """A flat view of the board (gaps of 12-14 px, beyond the print fit's) under a glare: a bright
    spot over its far corner mixes up to 0.9 of its light into the print, leaving saddles of a
    tenth of the print's contrast, with noise. Completed from the four tags of the opposite
    corner, with the contrast threshold scaled to the print's contrast around each prediction
    (``dim_gaps``) every corner is found (9 fewer without it when written, each in the glare),
    each within 0.5 px of its label. Their scores (the calibrator's weights), print correlations
    times the square of the print's share of contrast there (about 0.2), are under 0.1, against
    ``min_corr`` or more for the corners added where the print is clear. The corners found either
    way are where they were."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    H = np.array([[700.0, 30.0, 50.0], [-20.0, 690.0, 60.0], [0.05, 0.02, 1.0]])
    size = (420, 420)
    v = _sensor_view(g, H, size, 1.0)
    q = PlaneMaps(H[None])(g.points().numpy()[None, :, :2])[0]
    yy, xx = np.mgrid[0 : size[1], 0 : size[0]].astype(np.float32)
    spot = q[-1] - 30  # near the board's far corner
    glare = 0.9 * np.exp(-((xx - spot[0]) ** 2 + (yy - spot[1]) ** 2) / (2 * 110.0**2))
    img = (v * (1 - glare) + 0.95 * glare + np.random.default_rng(5).normal(0, 0.008, v.shape)).astype(np.float32)
    rim, allowed, smoothed = np.full(img.shape, 100.0, np.float32), np.ones(img.shape, bool), {}
    cand, _ = tag_candidates(img, allowed, TagConfig(), smoothed, rim)
    given = _anchor(g, [0, 1, 6, 7])
    plain, scaled = (
        complete_board(img, dict(smoothed), rim, cand, g, given, q[given], CompletionConfig(dim_gaps=lc), GridConfig()) for lc in (0.0, 1.0)
    )
    assert len(scaled.ids) == g.n_corners and len(plain.ids) <= g.n_corners - 5, (len(plain.ids), len(scaled.ids))
    assert np.linalg.norm(scaled.xy - q[scaled.ids], axis=1).max() < 0.5
    gained = np.setdiff1d(scaled.ids, plain.ids)
    assert (glare[tuple(np.rint(q[gained][:, ::-1]).astype(int).T)] > 0.6).all(), "a corner gained outside the glare"
    clear = ~np.isin(scaled.ids, given) & ~np.isin(scaled.ids, gained)
    assert (scaled.corr[np.isin(scaled.ids, gained)] < 0.1).all() and (scaled.corr[clear] >= CompletionConfig().min_corr).all()
    both = np.isin(scaled.ids, plain.ids)
    np.testing.assert_array_equal(scaled.xy[both], plain.xy)


def test_complete_board_finds_corners_of_small_tags_by_their_print():
    """Tags of 8-14 px seen 60-90 deg off-axis through a 200-degree UCM lens and blurred by 1 px
    (gaps of 3-4 px), completed from the four tags of one block: with the print fitted where the
    saddle fits fail, at least 40 more corners (85 -> 142 when written), each within 0.5 px of its label."""
    found = _completed_small_tags(1.0, [CompletionConfig(print_fit_gap_px=x) for x in (0.0, 7.0)], tol=0.5)
    assert found[1] >= found[0] + 40, found


def test_complete_board_finds_corners_just_inside_the_rim_by_their_print():
    """A flat view of a grey print (gaps of 6-7 px) cut by a black region along one row of corners,
    which lie 2.2 px inside it: given the corners more than 5 px inside, completion with the print
    fit at the rim also finds that row (where no saddle window fits), each within 0.15 px of its
    true position; without it, none of them. Nothing is reported in the black region."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    H = np.array([[420.0, 30.0, 180.0], [-20.0, -400.0, 420.0], [0.1, 0.05, 1.0]])
    v = _sensor_view(g, H, (560, 480), 0.9)
    rng = np.random.default_rng(5)
    to_image = PlaneMaps(H[None])
    P = g.points().numpy()[:, :2]
    q = to_image(P[None])[0]
    row = np.arange(g.n_corners) // g.nx
    ends = q[[6 * g.nx, 7 * g.nx - 1]]  # corner row 6 (the top of tag row 3): a straight line in this view
    n = np.array([-(ends[1] - ends[0])[1], (ends[1] - ends[0])[0]]) / np.linalg.norm(ends[1] - ends[0])
    n = n if (q[row == 7].mean(0) - ends[0]) @ n > 0 else -n  # towards row 7
    yy, xx = np.mgrid[0:480, 0:560]
    inside = ((np.stack([xx, yy], -1) - ends[0]) @ n) < 2.2
    img = np.where(inside, 0.3 + (v - 0.1) / 0.7 * 0.45, 0.02).astype(np.float32) + rng.normal(0, 0.01, v.shape).astype(np.float32)
    rim = cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_L2, 3)
    depth = 2.2 - (q - ends[0]) @ n  # px inside the region
    given = np.nonzero(depth > 5)[0]
    near_rim = set(np.nonzero(row == 6)[0].tolist())
    assert np.allclose(depth[list(near_rim)], 2.2, atol=1e-6) and (depth[row == 7] < 0).all()
    found = []
    for rim_px in (0.0, 1.5):
        cfg = CompletionConfig(print_fit_rim_px=rim_px)
        ids, xy, _, _ = complete_board(img, {}, rim, np.zeros((0, 2)), g, given, q[given], cfg, GridConfig())
        assert (depth[ids] > 0).all()
        err = np.linalg.norm(xy - q[ids], axis=1)
        assert err.max() < 0.15, f"corner {ids[err.argmax()]} is {err.max():.2f} px off"
        found.append(near_rim & set(ids.tolist()))
    assert not found[0] and len(found[1]) >= 0.6 * len(near_rim), (found, near_rim)
