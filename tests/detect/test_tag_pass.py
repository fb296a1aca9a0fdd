"""The tag pass finds Kalibr AprilGrid corners with their ids: rendered views through every camera
family (up to the rim), tags read with bit errors corrected or refused, and tags or boards that
are not the target ignored. Ground truth: the renderer's exact corner labels."""

from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch
from scipy.spatial import cKDTree

from cotrain.detect.detector import Detector
from cotrain.detect.grid_config import GridConfig
from cotrain.detect.image_circle import EquidistantLens
from cotrain.detect.lattice import Lattice
from cotrain.detect.print_model import CompletionConfig
from cotrain.detect.sampling import corner_rays, edge_contrast_kernel
from cotrain.detect.tag_candidates import RayNeighbours, _in_cone, edges_along
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_growth import edge_contrast, join_lattices, lattice_link, ray_step
from cotrain.detect.tag_pass import _view_of, tag_pass
from cotrain.detect.tag_placement import (
    Placement,
    _Board,
    consistent_boards,
    rays_agree,
    slipped_corr,
    tag_corr,
    tag_under,
    verified_corners,
)
from cotrain.detect.tag_reading import (
    TagCell,
    _row_medians,
    _turn_index,
    decode_bits,
    decode_many,
    look_at_tag,
    look_at_tags,
    otsu_split,
    page_order,
    side_points,
    tag_map,
)
from cotrain.detect.tag_seeds import _ASK_TREE, _NO_FOURTH, _seed_frames, _seed_quads, fourth_corner, looks_like_a_tag
from cotrain.geometry import cameras, poses
from cotrain.render.renderer import RenderConfig, Scene, render_scene, sample_draws
from cotrain.targets import TargetConfig, make_target
from cotrain.targets.aprilgrid import BORDER_BITS, CELLS, N_CODES, printed_bits

CLEAN = dict(p_occluder=0.0, p_no_target=0.0, p_motion=0.0, max_blur_sigma=0.3, p_distractor=0.0, p_jpeg=0.0)


def render(board, model: str, fov: float, eye, look, size=(1280, 720), seed: int = 0):
    """One clean rendering of ``board`` through a ``model`` camera looking from ``eye`` (board
    frame) at ``look``: uint8 image, labels (N, 2), visible (N,), and off-axis angle (N,) deg."""
    torch.set_num_threads(1)
    w, h = size
    rc = RenderConfig(height=h, width=w, target=board.cfg, **CLEAN)
    radius = 380.0
    params = cameras.make_camera(model, fov, w, h, radius)
    up = torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64)
    T = torch.linalg.inv(poses.look_at(torch.tensor(eye, dtype=torch.float64), torch.tensor(look, dtype=torch.float64), up))
    scene = Scene([model], [params], torch.tensor([float(fov)]), torch.tensor([radius]), T[None])
    out = render_scene(rc, board, scene, [sample_draws(seed, 0)])
    img = (out["image"][0, 0].numpy() * 255).round().astype(np.uint8)
    p_cam = poses.transform_points(T, board.points(torch.float64))
    angle = torch.rad2deg(torch.atan2(p_cam[:, :2].norm(dim=-1), p_cam[:, 2])).numpy()
    return img, out["corners"][0].numpy(), out["visible"][0].numpy(), angle


def centre(board):
    x0, y0, x1, y1 = board.extent()
    return [(x0 + x1) / 2, (y0 + y1) / 2, 0.0]


def check_ids(det, q, vis, tol=0.5):
    """Every reported corner is visible and within ``tol`` px of its own label."""
    assert vis[det.ids].all()
    err = np.linalg.norm(det.xy - q[det.ids], axis=1)
    assert err.max() < tol, f"worst corner {det.ids[err.argmax()]} is {err.max():.2f} px off"
    return err


@pytest.mark.parametrize(("distance", "aside", "print_"), [(1.25, 0.6, "clean"), (1.5, 0.0, "clean"), (1.45, 0.0, "grey")])
def test_a_whole_board_of_tags_under_ten_pixels_is_found_by_the_third_look(distance, aside, print_):
    """A board seen whole from 1.25-1.5 m through a 200-degree lens: tags of 7.8-9.2 px, data
    cells under a pixel, clean, or a grey print (black 0.2, white 0.75) blurred 0.6 px with noise
    of 0.02. No seed has cells of a pixel, so the first two looks find nothing; the third, with
    seeds of cells down to ``retry_min_cell_px`` (0.7), finds the board: every reported corner
    visible and within 0.5 px of its own label, all 144 (the grey print: 135 or more)."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(
        g, "kb4", 200, (c + [0.05, -0.03, distance]).tolist(), (c + [aside, 0.1 if print_ == "grey" else 0.0, 0.0]).tolist()
    )
    grey = img.astype(np.float32) / 255
    if print_ == "grey":
        grey = 0.2 + 0.55 * cv2.GaussianBlur(grey, (0, 0), 0.6)
        grey = np.clip(grey + np.random.default_rng(0).normal(0, 0.02, grey.shape), 0, 1).astype(np.float32)
    assert vis.all() and 7.5 < np.linalg.norm(q[1] - q[0]) < 9.5  # a tag side, px
    cfg = TagConfig()
    assert len(tag_pass(grey, g, replace(cfg, retry_min_cell_px=cfg.min_cell_px)).ids) == 0
    r = tag_pass(grey, g, cfg)
    check_ids(r, q, vis)
    assert len(r.ids) >= (144 if print_ == "clean" else 135)
    assert r.look == "small cells"  # cotrain.detect.retries: the look that found them


def test_a_grey_print_in_falling_light_is_found_by_the_fourth_look():
    """A board of 22 px tags through a 200-degree lens, printed grey on grey (contrast 0.12 of the
    clean print's) in light falling by a third across the frame, with noise of 0.01: its saddles
    and edges are under the pass's thresholds (set in intensity), so the first three looks find
    nothing. The fourth reads the frame with its contrast raised about the local mean
    (``retry_gain`` 3; at half resolution, the frame being 720 px high) and finds every corner
    within 0.5 px of its own label."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "kb4", 200, (c + [0.05, -0.03, 0.45]).tolist(), (c + [0.3, 0.1, 0.0]).tolist())
    assert vis.all() and 20 < np.linalg.norm(q[1] - q[0]) < 24  # a tag side, px
    light = np.linspace(0.5, 0.8, img.shape[1], dtype=np.float32)[None] / 0.65
    grey = (0.55 + 0.12 * (img.astype(np.float32) / 255 - 0.5)) * light + np.random.default_rng(0).normal(0, 0.01, img.shape)
    grey = np.clip(grey, 0, 1).astype(np.float32)
    cfg = TagConfig()
    assert len(tag_pass(grey, g, replace(cfg, retry_gain=0)).ids) == 0
    r = tag_pass(grey, g, cfg)
    check_ids(r, q, vis)
    assert len(r.ids) == g.n_corners
    assert r.look == "contrast raised"


def test_flat_view_finds_every_corner_at_its_label():
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 120, [c[0] + 0.02, c[1] - 0.03, 0.45], c)
    assert vis.all()
    det = Detector(target=g).detect(img)
    assert len(det.ids) == g.n_corners
    err = check_ids(det, q, vis)
    assert np.median(err) < 0.08


def test_the_quick_look_passes_every_tag_and_refuses_a_checker_square():
    """Before a quad of candidates is read as a tag, a quick look: its border ring darker than
    the gaps around it, and its data cells not all alike. Every tag of a flat view passes it, at
    full contrast and at a tenth of it (a grey print); a black square framed by white (a
    checkerboard's, or a dark patch) passes the ring test but not the data cells, and is not read,
    also where a gap point lies beyond the frame's edge."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 120, [c[0] + 0.02, c[1] - 0.03, 0.45], c)
    grey = img.astype(np.float32) / 255
    quads = q[g.tag_corners(np.arange(g.n_tags))]  # (T, 4, 2): Kalibr's tag corners, lattice order
    for image in (grey, 0.5 + 0.1 * (grey - 0.5)):
        assert all(looks_like_a_tag(image, quad, g.cfg.tag_spacing) for quad in quads)
    square = np.ones((200, 200), np.float32)
    square[60:140, 60:140] = 0.05
    quad = np.array([[60.0, 60.0], [140.0, 60.0], [140.0, 140.0], [60.0, 140.0]]) - 0.5
    assert not looks_like_a_tag(square, quad, 0.3)
    # A skewed black quad: refused inside the frame, and with one gap point beyond its edge (which
    # counts as failed, one may): its data cells, all inside, are still alike.
    for dx in (0, 3):
        framed = np.ones((200, 200), np.float32)
        skewed = np.array([[20.0, 60.0], [100.0, 60.0], [100.0, 140.0], [10.0, 140.0]]) - [dx, 0]
        cv2.fillConvexPoly(framed, np.round(skewed).astype(np.int32), 0.05)
        assert not looks_like_a_tag(framed, skewed, 0.3)
        framed[95:105, 50:60] = 1.0  # a white data cell
        assert looks_like_a_tag(framed, skewed, 0.3)
    square[95:105, 95:105] = 1.0  # one white data cell: not all alike
    assert looks_like_a_tag(square, quad, 0.3)


@pytest.mark.parametrize("model", ["kb4", "ucm", "eucm", "ds"])
def test_decodes_near_the_rim_of_each_camera_family(model):
    """The board seen 60-95 deg off-axis through a 200-degree lens of each family: corners found
    with their own ids, tags read there, none misplaced."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    eye = c + np.array([0.0, 0.0, 0.28])
    look = c + np.array([-0.5, 0.05, 0.0])  # the board lies far to the camera's side
    img, q, vis, angle = render(g, model, 200, eye.tolist(), look.tolist())
    assert vis.sum() > 40 and angle[vis].max() > 80
    det = Detector(target=g).detect(img)
    check_ids(det, q, vis)
    far = vis & (angle > 70)
    found = np.isin(np.nonzero(far)[0], det.ids).mean()
    assert found > 0.5, f"{found:.2f} of the corners beyond 70 deg found"


def test_bit_errors_are_corrected_up_to_the_limit_and_refused_beyond():
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    rng = np.random.default_rng(0)
    flip = rng.choice(36, size=12, replace=False)
    g.printed = g.printed.copy()
    g.printed[7].flat[flip[:1]] ^= 1  # tag 7: one flipped bit
    for t in range(20, 36):  # tags 20..35: a third of their bits flipped
        g.printed[t].flat[flip] ^= 1
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 120, [c[0], c[1], 0.45], c)
    det = Detector(target=g).detect(img)
    check_ids(det, q, vis)
    res = tag_pass(img.astype(np.float32) / 255, g)
    read = dict(zip(res.tags.tolist(), res.hamming.tolist()))
    assert read.get(7) == 1  # corrected
    assert not set(read) & set(range(20, 36))  # refused: not read as tags
    # Their corners get no ids from the lattice growth; completion may find them from the placed
    # board (the print check sees their borders and crossing squares), each at its own label.
    bad_corners = set(g.tag_corners(np.arange(20, 36)).ravel().tolist()) - set(g.tag_corners(np.arange(20)).ravel().tolist())
    grown = Detector(target=g, tags=TagConfig(complete=CompletionConfig(rounds=0))).detect(img)
    assert not set(grown.ids.tolist()) & bad_corners


def test_decode_bits_known_codes_in_every_turn():
    page = printed_bits(40)[17].ravel() * 2.0 - 1  # tag 17 as printed, +1 white
    for m in range(4):
        lattice = page[_turn_index()[m]]  # the same cells read in lattice order under turn m
        np.testing.assert_array_equal(page_order(lattice, m), page)
        assert decode_bits(lattice > 0) == (17, m, 0)
        lattice[5] *= -1
        assert decode_bits(lattice > 0) == (17, m, 1)


def test_wild_tags_and_a_second_board_give_no_corners():
    """Left half: the target. Right half: a second AprilGrid printed with other tags (ids 36..71).
    Pasted on the target's background: free tag36h11 tags, one with an id that is on the target."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    other = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    other.printed = printed_bits(72)[36:].copy()
    c = np.array(centre(g))
    eye = c + np.array([0.0, 0.0, 0.35])
    a, q, vis, _ = render(g, "kb4", 180, eye.tolist(), (c - [0.4, 0, 0]).tolist())
    b, _, _, _ = render(other, "kb4", 180, eye.tolist(), (c + [0.4, 0, 0]).tolist())
    assert vis.sum() > 60 and q[vis, 0].max() < 600  # the target stays in the left half
    img = np.concatenate([a[:, :640], b[:, 640:]], 1)
    d = cv2.aruco.getPredefinedDictionary(cv2.aruco.DICT_APRILTAG_36h11)
    for tag, (x, y) in ((5, (40, 600)), (300, (150, 600))):
        m = cv2.aruco.generateImageMarker(d, tag, 60, borderBits=2)
        img[y - 10 : y + 70, x - 10 : x + 70] = 255
        img[y : y + 60, x : x + 60] = m
    det = Detector(target=g).detect(img)
    assert len(det.ids) > 0.8 * vis.sum()
    check_ids(det, q, vis)
    assert (det.xy[:, 0] < 640).all()
    # The second board's tags are read and counted as foreign, each once (36 on that board).
    res = tag_pass(img.astype(np.float32) / 255, g)
    assert 10 <= res.foreign_tags <= 36


def tag_image(t: int, px: float, blur: float, spacing: float = 0.3, sub: int = 8):
    """Tag ``t`` as Kalibr prints it, ``px`` pixels across, white gaps around, area-sampled and
    blurred by ``blur`` px (sigma); grey print (0.15 .. 0.85). Returns the float32 image and the
    tag's corners (4, 2): top-left, top-right, bottom-right, bottom-left (pixel centres at integers)."""
    cells = np.zeros((CELLS, CELLS))
    cells[BORDER_BITS:-BORDER_BITS, BORDER_BITS:-BORDER_BITS] = printed_bits(t + 1)[t][::-1]  # page rows y up -> image rows
    g = int(round(spacing * CELLS))
    canvas = np.ones((CELLS + 2 * g, CELLS + 2 * g))
    canvas[g : g + CELLS, g : g + CELLS] = cells
    hi = np.kron(canvas, np.ones((sub, sub))).astype(np.float32)
    scale = px / (CELLS * sub)
    n = int(round(hi.shape[0] * scale))
    img = cv2.GaussianBlur(cv2.resize(hi, (n, n), interpolation=cv2.INTER_AREA), (0, 0), blur)
    o = g * sub * scale - 0.5
    corners = np.array([[o, o], [o + px, o], [o + px, o + px], [o, o + px]])
    return (0.15 + 0.7 * img).astype(np.float32), corners


def test_blurred_small_tags_read_after_sharpening():
    """Tags 20 px across (cells of 2 px) blurred by 1 px: every one of the 36 board tags reads as
    itself within AprilTag's 2 bit errors; without the sharpening of the cells, white cells among
    black ones read black and some tags do not."""

    def decoded(sharpen: float) -> int:
        n = 0
        for t in range(36):
            img, c = tag_image(t, 20, 1.0)
            tid, _, ham = decode_bits(look_at_tag(img, c, 0.3, sharpen=sharpen).white)
            n += tid == t and ham <= 2
        return n

    assert decoded(TagConfig().sharpen) == 36
    assert decoded(0.0) < 33


def test_small_gaps_keep_corners_whose_final_fit_fails():
    """Tags about 13 px across (gaps of 4 px) blurred by 1 px: the final fit's smallest window
    reaches across the crossing squares and fails at some true corners; those keep their lattice
    positions, so more corners are reported, each within 0.6 px of its label."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 200, [c[0] + 0.02, c[1] - 0.03, 1.1], c)
    noise = np.random.default_rng(0).normal(0, 3, img.shape)
    img = np.clip(cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.0) + noise, 0, 255).astype(np.uint8)
    grown = CompletionConfig(rounds=0)  # completion would find the dropped ones again
    kept = Detector(target=g, tags=TagConfig(complete=grown)).detect(img)
    dropped = Detector(target=g, tags=TagConfig(keep_unfitted_px=0.0, complete=grown)).detect(img)
    assert len(kept.ids) >= len(dropped.ids) + 5
    check_ids(kept, q, vis, tol=0.6)


def test_otsu_split_matches_opencv():
    """The two-class split of 36 values is OpenCV's Otsu threshold on the same uint8 values."""
    rng = np.random.default_rng(3)
    for _ in range(20):
        share = rng.uniform(0.2, 0.8)
        v = np.where(rng.random(36) < share, rng.normal(170, 30, 36), rng.normal(80, 30, 36))
        v = np.clip(v, 0, 255).round().astype(np.uint8)
        thr, _ = cv2.threshold(v[None], 0, 255, cv2.THRESH_BINARY + cv2.THRESH_OTSU)
        np.testing.assert_array_equal(v > otsu_split(v.astype(np.float64)), v > thr)


def x_junction(theta1: float, theta2: float, size: int = 41, blur: float = 1.0) -> np.ndarray:
    """An X-junction at the image centre whose edges run at angles theta1 and theta2 (rad, x right,
    y down): dark where the signed distances to the two lines have the same sign."""
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64) - size // 2
    d1 = -np.sin(theta1) * xx + np.cos(theta1) * yy
    d2 = -np.sin(theta2) * xx + np.cos(theta2) * yy
    img = np.where(d1 * d2 > 0, 0.2, 0.8).astype(np.float32)
    return cv2.GaussianBlur(img, (0, 0), blur)


def test_corner_rays_follow_sheared_edges():
    """A junction whose edges meet at 55 deg (shear at the rim): the four rays lie along the two
    edges, both ways, to within 2 deg; an edge and a flat patch have no rays."""
    t1, t2 = np.radians(20.0), np.radians(75.0)
    img = x_junction(t1, t2)
    c = np.array([[20.0, 20.0]])
    rays = corner_rays(img, c, np.array([5.0]))[0]
    got = np.sort(np.degrees(np.arctan2(rays[:, 1], rays[:, 0])) % 360)
    np.testing.assert_allclose(got, [20, 75, 200, 255], atol=2.0)
    edge = np.where(np.mgrid[0:41, 0:41][1] < 20.3, 0.2, 0.8).astype(np.float32)
    flat = np.full((41, 41), 0.5, np.float32)
    assert np.isnan(corner_rays(edge, c, np.array([5.0]))).all()
    assert np.isnan(corner_rays(flat, c, np.array([5.0]))).all()


def test_corners_off_their_junctions_fail_the_ray_check():
    """On a rendered board, every labelled corner's steps to its lattice neighbours leave along its
    own edge rays; a corner moved a third of the way into its tag (where a data junction would be
    taken for it) does not."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 150, [c[0] + 0.05, c[1] - 0.04, 0.4], c)
    assert vis.all()
    ids = np.arange(g.n_corners)
    ab = np.stack([ids % (2 * g.tc), ids // (2 * g.tc)], 1)  # Kalibr's grid columns and rows
    grey = cv2.GaussianBlur(img.astype(np.float32) / 255, (0, 0), 0.7)
    assert rays_agree(Lattice(q.astype(np.float64), ab, np.zeros(len(q), bool)), grey, g.cfg.tag_spacing, TagConfig()).all()
    moved = q.astype(np.float64).copy()
    t = 14  # tag 14: its first corner moved toward the tag's centre
    k = g.tag_corners(t)
    moved[k[0]] += (q[k].mean(0) - q[k[0]]) / 3
    ok = rays_agree(Lattice(moved, ab, np.zeros(len(q), bool)), grey, g.cfg.tag_spacing, TagConfig())
    assert not ok[k[0]]
    assert ok.sum() >= len(q) - 5  # its neighbours may lose their step to it, nothing else


def test_small_gaps_read_their_rays_with_a_looser_angle():
    """Tags about 10 px across (gaps under 3.5 px) blurred by 1.2 px with noise: on the smallest
    ray circle (1.5 px) the rays' angles are coarse, and with the 20 deg of larger tags many true
    corners fail; with completion's ``max_ray_angle`` there most pass. (A corner slid into a larger tag still
    fails: the test above.)"""
    g = make_target(TargetConfig(kind="aprilgrid"))
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 200, [c[0] + 0.02, c[1] - 0.03, 1.2], c)
    assert vis.all()
    noise = np.random.default_rng(0).normal(0, 6, img.shape)
    grey = np.clip(cv2.GaussianBlur(img.astype(np.float32), (0, 0), 1.2) + noise, 0, 255).astype(np.float32) / 255
    grey = cv2.GaussianBlur(grey, (0, 0), 0.7)  # as the tag pass smooths for its rays
    ids = np.arange(g.n_corners)
    lat = Lattice(q.astype(np.float64), np.stack([ids % (2 * g.tc), ids // (2 * g.tc)], 1), np.zeros(len(q), bool))
    gap_steps = [i for i in ids if i % (2 * g.tc) % 2 == 1 and i % (2 * g.tc) < 2 * g.tc - 1]  # corner column 1 -> 2, ...
    assert np.median(np.linalg.norm(q[gap_steps] - q[np.array(gap_steps) + 1], axis=1)) < TagConfig().small_gap_px
    loose = rays_agree(lat, grey, g.cfg.tag_spacing, TagConfig())
    strict_angle = CompletionConfig(max_ray_angle=GridConfig().seed_axis_angle)
    strict = rays_agree(lat, grey, g.cfg.tag_spacing, TagConfig(complete=strict_angle))
    assert loose.sum() >= strict.sum() + 10
    assert loose.mean() > 0.85


def test_slipped_corr_is_the_best_match_among_the_tags_a_one_tag_slip_would_give():
    """A clean read of tag 14 correlates with its own code by nearly 1 and with the codes of tags
    8, 13, 15 and 20 (where a lattice slipped by one tag would put it) far less; read where tag 13
    is expected, the slip's best match is tag 14 itself."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    img, c = tag_image(14, 40, 0.5)
    look = look_at_tag(img, c, 0.3, sharpen=TagConfig().sharpen)
    tag, turn, ham = decode_bits(look.white)
    assert (tag, ham) == (14, 0)
    cell = TagCell((0, 0), look, tag, turn, ham, True, 40.0)
    own = tag_corr(look.soft, turn, np.array([14]))[0]
    assert own > 0.95
    assert slipped_corr(cell, 14, turn, g) < 0.5
    others = tag_corr(look.soft, turn, np.array([8, 13, 15, 20]))
    assert slipped_corr(cell, 14, turn, g) == pytest.approx(others.max())
    assert slipped_corr(cell, 13, turn, g) == pytest.approx(own)  # 14 is beside 13


def test_edges_along_finds_segments_on_an_edge_only():
    """On a junction's image: segments along either of its edges are edges; a segment through the
    middle of a sector (across no edge) and one crossing an edge are not."""
    t1, t2 = np.radians(20.0), np.radians(75.0)
    img = x_junction(t1, t2, size=81)
    p = np.full((4, 2), 40.0)
    along1 = 30 * np.array([np.cos(t1), np.sin(t1)])
    along2 = -30 * np.array([np.cos(t2), np.sin(t2)])
    mid = 30 * np.array([np.cos((t1 + t2) / 2), np.sin((t1 + t2) / 2)])  # inside one sector
    start = p[3] + 15 * np.array([np.cos(t1), np.sin(t1)]) - 10 * np.array([-np.sin(t1), np.cos(t1)])
    p[3] = start
    across = 20 * np.array([-np.sin(t1), np.cos(t1)])  # crosses edge 1
    ok = edges_along(img, p, np.stack([along1, along2, mid, across]), 0.04)
    np.testing.assert_array_equal(ok, [True, True, False, False])


def test_ray_step_takes_the_candidate_along_a_ray_in_the_steps_direction():
    """Of a corner's nearest ray neighbours, the one within 40 deg of the predicted step and of a
    length the growth allows is taken; none when it is already a lattice corner, when the step
    points elsewhere, or when it is twice as long as predicted."""
    cfg = TagConfig()
    xy = np.array([[0.0, 0.0], [30.0, 4.0], [0.0, 28.0], [-31.0, 0.0], [60.0, 8.0]])
    tree = cKDTree(xy)
    options = np.full((2, 2, cfg.ray_options, 2), np.nan)
    options[0, 0, 0] = xy[1]  # ray 0: toward candidate 1 (8 deg below the x axis direction)
    options[0, 0, 1] = xy[4]  # a farther one on the same ray: never taken
    options[1, 0, 0] = xy[2]
    options[0, 1, 0] = xy[3]
    p = xy[0]
    assert ray_step(p, options, np.array([28.0, -4.0]), xy, tree, set(), cfg) == 1  # 16 deg off: taken
    assert ray_step(p, options, np.array([28.0, -4.0]), xy, tree, {1}, cfg) is None
    assert cfg.ray_step_angle == 40.0
    assert ray_step(p, options, np.array([20.0, 20.0]), xy, tree, set(), cfg) == 1  # 37 deg off ray 0: taken
    assert ray_step(p, options, np.array([15.0, -26.0]), xy, tree, set(), cfg) is None  # 68 deg off ray 0, 150 off ray 1
    assert ray_step(p, options, np.array([15.0, 2.0]), xy, tree, set(), cfg) is None  # twice the predicted length
    assert ray_step(p, options, np.array([0.0, 30.0]), xy, tree, set(), cfg) == 2
    # With the options' candidates given (as axis_neighbours finds them), the same answers without
    # looking them up; the targets, not the tree, are what is returned.
    targets = np.full((2, 2, cfg.ray_options), -1)
    targets[0, 0, 0], targets[0, 0, 1], targets[1, 0, 0], targets[0, 1, 0] = 1, 4, 2, 3
    for v, used in (([28.0, -4.0], set()), ([28.0, -4.0], {1}), ([20.0, 20.0], set()), ([15.0, -26.0], set()), ([0.0, 30.0], set())):
        assert ray_step(p, options, np.array(v), xy, tree, used, cfg, targets) == ray_step(p, options, np.array(v), xy, tree, used, cfg)
    relabelled = targets.copy()
    relabelled[0, 0, 0] = 3
    assert ray_step(p, options, np.array([28.0, -4.0]), xy, tree, set(), cfg, relabelled) == 3


def test_seed_frames_name_the_candidates_their_long_steps_lead_to():
    """Every step frame a seed gets is oriented (a x b > 0 in the image, a turned frame swaps its
    axes) and names the candidates its two long steps end on; the surest frame, the nearest long
    neighbours with the shorter neighbours the other way as gaps, comes first."""
    cfg = TagConfig()
    p0 = np.array([100.0, 100.0])
    xy = np.array([p0, p0 + [30.0, 2.0], p0 + [-9.0, -0.5], p0 + [1.0, 29.0], p0 + [0.0, -10.0], p0 + [-31.0, 1.0]])
    nbr = np.full((2, 2, cfg.ray_options, 2), np.nan)
    index = np.full((2, 2, cfg.ray_options), -1)
    for (axis, way, k), j in {(0, 0, 0): 1, (0, 1, 0): 2, (0, 1, 1): 5, (1, 0, 0): 3, (1, 1, 0): 4}.items():
        nbr[axis, way, k] = xy[j] - p0
        index[axis, way, k] = j
    frames = _seed_frames(nbr, index, 0.3)
    assert len(frames) == 6  # two options along -a, one along each other way: 2 + 2 + 1 + 1 quadrant pairs
    for frame, ja, jb in frames:
        np.testing.assert_allclose(frame[0, 0], xy[ja] - p0)
        np.testing.assert_allclose(frame[1, 0], xy[jb] - p0)
        assert frame[0, 0, 0] * frame[1, 0, 1] - frame[0, 0, 1] * frame[1, 0, 0] > 0
    first, ja, jb = frames[0]
    assert (ja, jb) == (1, 3)
    np.testing.assert_allclose(first[:, 1], [[9.0, 0.5], [0.0, 10.0]])  # the gaps behind the corner, pointing +a and +b
    assert {(a, b) for _, a, b in frames} >= {(4, 1), (3, 2)}  # turned quadrants: axes swapped to keep a x b > 0


@pytest.mark.parametrize("with_lens", [False, True])
def test_compiled_seed_quads_are_the_readable_search(with_lens):
    """The seeds' compiled quad search (:func:`_seed_quads`) gives, for every candidate of a
    jittered lattice of junctions with random ray neighbours (some missing, some pointing
    nowhere useful), the frames of :func:`_seed_frames` in their order and the fourth corners of
    :func:`fourth_corner`, exactly; through a lens and in pixels."""
    cfg = TagConfig()
    rng = np.random.default_rng(5)
    g = np.stack(np.meshgrid(np.arange(8), np.arange(8)), -1).reshape(-1, 2)
    xy = 100.0 + g * [26.0, 24.0] + rng.normal(0, 1.5, g.shape)  # some steps fall outside the cones
    K = len(xy)
    tree = cKDTree(xy)
    step = np.full((K, 2, 2, cfg.ray_options, 2), np.nan)
    index = np.full((K, 2, 2, cfg.ray_options), -1)
    for k in range(K):
        for axis in range(2):
            for way in range(2):
                n = rng.integers(0, cfg.ray_options + 1)  # 0 .. 3 options
                d = np.zeros(2)
                d[axis] = 1 if way == 0 else -1
                target = xy[k] + d * [26.0, 24.0]
                _, near = tree.query(target + rng.normal(0, 6, (n, 2)))
                for o, j in enumerate(np.atleast_1d(near)[:n]):
                    if j != k:
                        step[k, axis, way, o], index[k, axis, way, o] = xy[j] - xy[k], j
    nbr = RayNeighbours(step, index)
    lens = EquidistantLens((420.0, 380.0), 150.0) if with_lens else None
    rays = lens.lift(xy) if with_lens else np.zeros((0, 3))
    cos_min = np.cos(np.radians(cfg.ray_step_angle))
    asked = found = 0
    for seed in range(K):
        frames = _seed_frames(step[seed], index[seed], 0.3)
        got = _seed_quads(
            seed, step, index, xy, rays, with_lens, *((420.0, 380.0, 150.0) if with_lens else (0.0, 0.0, 1.0)),
            0.3, cos_min, cfg.min_step_ratio, cfg.max_step_ratio, cfg.fourth_radius,
        )  # fmt: skip
        assert len(got[0]) == len(frames)
        for f, (frame, ja, jb) in enumerate(frames):
            np.testing.assert_array_equal(got[0][f], frame)
            assert (got[1][f], got[2][f]) == (ja, jb)
            want = fourth_corner(xy, nbr, tree, (seed, ja, jb), cfg, lens, rays.tolist() if with_lens else None)
            j = int(got[3][f])
            # Its parallelogram corner and radius, to the last units (numba's hypot is the C library's).
            p0, pa, pb = xy[seed], xy[ja], xy[jb]
            r = cfg.fourth_radius * min(np.hypot(*(pa - p0)), np.hypot(*(pb - p0)))
            assert got[5][f] == pytest.approx(r, rel=1e-12)
            if not with_lens:
                np.testing.assert_allclose(got[4][f], pa + pb - p0, rtol=1e-12)
            if j == _ASK_TREE:
                asked += 1
                near = tree.query_ball_point(got[4][f], got[5][f])
                j = int(near[0]) if len(near) == 1 else _NO_FOURTH
            assert j == (_NO_FOURTH if want is None else want)
            found += want is not None
    assert asked > 10 and found > 10  # both ways of finding the fourth corner were exercised


def test_compiled_edge_contrast_is_the_readable_one():
    """The growth's edge test, compiled (``sampling.edge_contrast_kernel``), gives :func:`edge_contrast`'s
    value exactly: on random segments over a noisy image with an image circle, cut by the rim, off
    the image, and with one, two or three sample pairs inside."""
    rng = np.random.default_rng(8)
    H, W = 90, 120
    img = cv2.GaussianBlur(rng.random((H, W)).astype(np.float32), (0, 0), 2.0)
    inside = np.zeros((H, W), np.uint8)
    cv2.circle(inside, (60, 45), 40, 1, -1)
    rim = cv2.distanceTransform(inside, cv2.DIST_L2, 3)
    kinds = {"nan": 0, "zero": 0, "value": 0}
    for _ in range(3000):
        p, q = rng.uniform([-10, -10], [W + 10, H + 10], 2), rng.uniform([-10, -10], [W + 10, H + 10], 2)
        if rng.random() < 0.7:
            q = p + rng.normal(0, 8, 2)
        n = rng.normal(size=2)
        n /= np.linalg.norm(n)
        depth = rng.uniform(0.5, 4.0)
        want = edge_contrast(img, p, q, n, depth, rim)
        got = edge_contrast_kernel(img, rim, p[0], p[1], q[0], q[1], n[0], n[1], depth)
        if np.isnan(want):
            assert np.isnan(got)
            kinds["nan"] += 1
        else:
            assert got == want
            kinds["zero" if want == 0 else "value"] += 1
    assert min(kinds.values()) > 50


def test_in_cone_lists_the_nearest_neighbours_within_each_rays_cone():
    """axis_neighbours' cones, compiled (``_in_cone``), are the columns numpy's masks give: per
    candidate and ray, the j-th neighbour (nearest first) whose cosine to the ray exceeds the
    limit, among neighbours at least 1 px away and found (a k-d tree pads missing ones with inf),
    with rays of unknown direction (zero) matching nothing."""
    rng = np.random.default_rng(3)
    K, n, tries = 60, 40, 5
    xy = rng.uniform(0, 100, (K, 2))
    xy[1] = xy[0] + 0.5  # a pair under 1 px apart
    d, nb = cKDTree(xy).query(xy, k=n + 5)
    d[:, -5:], nb[:, -5:] = np.inf, K  # as the tree pads a query beyond its points
    v = xy[np.minimum(nb, K - 1)] - xy[:, None]
    a = rng.uniform(0, 2 * np.pi, (K, 4))
    rays = np.stack([np.cos(a), np.sin(a)], -1)
    rays[::7, 2] = 0.0
    cos_max = np.cos(np.radians(30.0))
    got = _in_cone(v, d, rays, cos_max, tries)
    ok = np.isfinite(d) & (d >= 1.0)
    cos = np.einsum("knd,krd->knr", v, rays) / np.where(ok, d, 1.0)[..., None]
    for r in range(4):
        hit = ok & (cos[..., r] > cos_max)
        rank = np.cumsum(hit, 1)
        for j in range(tries):
            at = hit & (rank == j + 1)
            np.testing.assert_array_equal(got[:, r, j], np.where(at.any(1), at.argmax(1), -1))
    assert (got[:, :, 0] >= 0).mean() > 0.5 and (got[:, :, -1] < 0).any()
    assert (got[::7, 2] < 0).all()


def test_row_medians_are_numpys():
    """The tag reads' medians (``_row_medians``) are ``np.median(x, 1)`` to the bit and in its
    type, for odd and even rows, float32 and float64, with ties."""
    rng = np.random.default_rng(5)
    for n in (12, 24, 36, 64, 65):
        for dtype in (np.float32, np.float64):
            x = rng.random((40, n)).astype(dtype)
            x[::4, :3] = x[::4, 3:6]
            want = np.median(x, 1)
            got = _row_medians(x)
            assert got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)


def test_edges_along_a_narrow_border_needs_a_shallow_look():
    """A 4 px dark strip (a foreshortened tag's border) between the light gap and black and white
    data cells: sampled 15 % of a 60 px segment (9 px) aside, the far samples fall on the data and
    the segment is not an edge; sampled at most 2 px aside, it is."""
    img = np.full((60, 100), 0.85, np.float32)
    img[30:34] = 0.15  # the border, below the gap
    img[34:] = np.where((np.arange(100) // 6) % 2 == 0, 0.85, 0.15)[None]  # data cells 6 px wide beyond it
    p, step = np.array([[20.0, 29.5]]), np.array([[60.0, 0.0]])
    assert not edges_along(img, p, step, 0.04)[0]
    assert edges_along(img, p, step, 0.04, np.array([2.0]))[0]


def opencv_fisheye_view(g, rvec, tvec, K, D, size=(1280, 960), texture_px=2400):
    """The board seen through OpenCV's equidistant fisheye model (cv2.fisheye), rendered without
    our renderer: a flat print at ``texture_px`` across (grey white 0.72, black 0.1), looked up per
    output pixel by inverting the lens with cv2.fisheye.undistortPoints and intersecting the ray
    with the board plane (pose rvec, tvec: board -> camera). Glare (a bright blob), blur and noise
    on top. Returns the uint8 image, corner labels (N, 2) and which lie in the view, within 87 deg
    of the axis."""
    x0, y0, x1, y1 = g.extent()
    s = texture_px / (x1 - x0)
    H_t, W_t = int((y1 - y0) * s), texture_px
    u, v = np.meshgrid(np.arange(W_t), np.arange(H_t))
    xy = np.stack([x0 + (u + 0.5) / s, y1 - (v + 0.5) / s], -1)  # texture rows top-down: board y decreasing
    tex = g.intensity(torch.from_numpy(xy))[0].numpy().astype(np.float32)
    tex = 0.1 + 0.62 * tex
    w, h = size
    pix = np.stack(np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64)), -1).reshape(-1, 1, 2)
    m = cv2.fisheye.undistortPoints(pix, K, D).reshape(-1, 2)  # normalised rays (x, y, 1)
    R, _ = cv2.Rodrigues(rvec)
    ray_b = (R.T @ np.concatenate([m, np.ones((len(m), 1))], 1).T).T  # in the board frame
    o_b = -R.T @ tvec.reshape(3)
    lam = -o_b[2] / ray_b[:, 2]
    p = o_b[None] + lam[:, None] * ray_b
    front = lam > 0
    map_x = ((p[:, 0] - x0) * s - 0.5).reshape(h, w).astype(np.float32)
    map_y = ((y1 - p[:, 1]) * s - 0.5).reshape(h, w).astype(np.float32)
    img = cv2.remap(tex, map_x, map_y, cv2.INTER_AREA, borderValue=0.45)
    img[~front.reshape(h, w)] = 0.45
    yy, xx = np.mgrid[0:h, 0:w]
    img += 0.25 * np.exp(-((xx - 0.6 * w) ** 2 + (yy - 0.4 * h) ** 2) / (2 * (0.15 * w) ** 2))  # glare
    theta_max = np.radians(90)  # cv2.fisheye divides by z: it sees in front of the camera only (a 180-degree circle)
    r = np.hypot(xx - K[0, 2], yy - K[1, 2])
    t2 = theta_max**2
    img[r > K[0, 0] * theta_max * (1 + D[0] * t2 + D[1] * t2**2 + D[2] * t2**3 + D[3] * t2**4)] = 0.0
    img = cv2.GaussianBlur(img, (0, 0), 0.8) + np.random.default_rng(0).normal(0, 0.015, img.shape)
    q, _ = cv2.fisheye.projectPoints(g.points(torch.float64).numpy()[None], rvec, tvec, K, D)
    p_cam = (R @ g.points(torch.float64).numpy().T + tvec.reshape(3, 1)).T
    theta = np.arctan2(np.hypot(p_cam[:, 0], p_cam[:, 1]), p_cam[:, 2])
    q = q[0]
    inside = (theta < theta_max - 0.05) & (q[:, 0] > 2) & (q[:, 0] < w - 3) & (q[:, 1] > 2) & (q[:, 1] < h - 3)
    return (np.clip(img, 0, 1) * 255).round().astype(np.uint8), q, inside


def test_another_renderer_opencv_fisheye_with_glare_and_a_grey_print():
    """The board rendered by OpenCV's fisheye model (not our renderer: a point-sampled print warped by
    cv2.remap), turned 50-75 deg and seen up to 87 deg off-axis, with glare, a grey print and noise:
    nearly every corner found, each within 1 px of OpenCV's projection with its own id (median
    under 0.15 px)."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    K = np.array([[300.0, 0, 640], [0, 300.0, 480], [0, 0, 1]])
    D = np.array([0.02, -0.01, 0.003, -0.0005])
    x0, y0, x1, y1 = g.extent()
    c = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    facing = np.diag([1.0, -1.0, -1.0])  # the print faces the camera: board y up is image y down
    for turn, at in (([0.3, 0.85, 0.1], [0.25, 0.05, 0.35]), ([0.2, 1.3, 0.3], [0.3, 0.1, 0.2])):
        R = cv2.Rodrigues(np.array(turn))[0] @ facing
        rvec, tvec = cv2.Rodrigues(R)[0].ravel(), np.array(at) - R @ c
        img, q, inside = opencv_fisheye_view(g, rvec, tvec, K, D)
        assert inside.sum() > 100
        det = Detector(target=g).detect(img)
        err = np.linalg.norm(det.xy - q[det.ids], axis=1)
        assert err.max() < 1.0, f"corner {det.ids[err.argmax()]} is {err.max():.2f} px off"
        assert np.median(err) < 0.15
        assert np.isin(np.nonzero(inside)[0], det.ids).mean() > 0.9


def test_another_renderer_close_boards_at_the_rim_read_through_the_guessed_lens():
    """Boards 20-25 cm from the lens, 75-85 deg off-axis, rendered by OpenCV's fisheye model (not
    our renderer): tags read and boards completed through the equidistant lens guessed from the
    image circle (the true lens: Kannala-Brandt, 180 degrees) find over 1.5 times the corners that
    pixel homographies find, every one within 1 px of OpenCV's projection with its own id."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    K = np.array([[300.0, 0, 640], [0, 300.0, 480], [0, 0, 1]])
    D = np.array([0.02, -0.01, 0.003, -0.0005])
    x0, y0, x1, y1 = g.extent()
    c = np.array([(x0 + x1) / 2, (y0 + y1) / 2, 0.0])
    facing = np.diag([1.0, -1.0, -1.0])
    found = {"lens": 0, "pixels": 0}
    for turn, at in (([0.33, -0.04, -0.35], [0.109, -0.216, 0.01]), ([-0.09, 0.15, 0.06], [0.138, -0.199, 0.055])):
        R = cv2.Rodrigues(np.array(turn))[0] @ facing
        rvec, tvec = cv2.Rodrigues(R)[0].ravel(), np.array(at) - R @ c
        img, q, inside = opencv_fisheye_view(g, rvec, tvec, K, D)
        grey = img.astype(np.float32) / 255
        for name, cfg in (("lens", TagConfig()), ("pixels", TagConfig(grid=GridConfig(lens_fov=0.0)))):
            r = tag_pass(grey, g, cfg)
            err = np.linalg.norm(r.xy - q[r.ids], axis=1)
            assert err.max() < 1.0, f"{name}: corner {r.ids[err.argmax()]} is {err.max():.2f} px off"
            found[name] += int(np.isin(np.nonzero(inside)[0], r.ids).sum())
    assert found["lens"] > 1.5 * found["pixels"], found


def _board_lattice(ab: np.ndarray) -> np.ndarray:
    """Pixels of lattice corners ab (K, 2) on a tilted AprilGrid-like grid: tag sides 30 px, gaps 9 px."""
    step = lambda m: (m // 2) * 39.0 + (m % 2) * 30.0  # noqa: E731
    x, y = step(ab[:, 0]), step(ab[:, 1])
    c, s = np.cos(0.3), np.sin(0.3)
    return np.stack([100 + c * x - s * y, 200 + s * x + c * y], 1)


def _offset_putting(g, tag: int, turn: int) -> np.ndarray:
    """The board offset under which turn ``turn`` puts tag ``tag`` on lattice tag cell (0, 0)."""
    b0 = g.ij_of(g.tag_corners(np.array([tag]))[:, 0])[0]
    offsets = [b0 + (dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1)]
    return next(o for o in offsets if tag_under(np.array([(0, 0)]), turn, o, g)[0] == tag)


def test_lattice_link_and_join_recover_one_board_from_two_growths():
    """Two growths of one 8 x 8 lattice overlapping in two columns, the second in its own
    coordinates (turned by a quarter, its tag cell (0, 0) on a tag of the first): joined, they are
    the whole lattice in the first one's coordinates. An offset by one (tags onto gaps) does not
    link; a corner of the second at another place than the first's on the same coordinate is in
    conflict: outvoted, it is dropped from the join; where conflicts are not outvoted, no link."""
    a, b = np.meshgrid(np.arange(8), np.arange(8))
    ab = np.stack([a.ravel(), b.ravel()], 1)
    xy = _board_lattice(ab)
    left, right = ab[:, 0] <= 4, ab[:, 0] >= 3
    A = Lattice(xy[left], ab[left], np.zeros(left.sum(), bool))
    R = np.array([[0, -1], [1, 0]])  # ab_A = R ab_B + off
    off = np.array([5, -2])  # the second's tag cell (0, 0) is the first's tag cell (4, -2)
    ab_b = (ab[right] - off) @ R  # R^-1 = R^T: A's corner (a, b) is B's (b + 2, 5 - a)
    B = Lattice(xy[right], ab_b, np.zeros(right.sum(), bool))
    M, o, conflicts = lattice_link(A, B, 1.0)
    np.testing.assert_array_equal(M, R)
    np.testing.assert_array_equal(o, off)
    assert conflicts == 0
    (J,) = join_lattices([A, B], 1.0)
    assert len(J.ab) == 64
    np.testing.assert_allclose(J.xy[np.lexsort(J.ab.T[::-1])], xy[np.lexsort(ab.T[::-1])])
    # Shifted by one lattice step (the second's tags on the first's gaps): no link.
    assert lattice_link(A, Lattice(B.xy, B.ab + [1, 0], B.filled), 1.0) is None
    # One corner of the second moved onto a neighbour's place: a conflict, outvoted and dropped.
    moved = B.xy.copy()
    k = int(np.nonzero((ab[right] == [4, 3]).all(1))[0][0])  # shared with A
    moved[k] = xy[(ab == [4, 4]).all(1)][0] + 0.2
    M, o, conflicts = lattice_link(A, Lattice(moved, B.ab, B.filled), 1.0)
    assert conflicts == 1
    (J,) = join_lattices([A, Lattice(moved, B.ab, B.filled)], 1.0)
    assert (4, 3) not in J.where and (4, 4) not in J.where and len(J.ab) == 62
    # Three shared corners (A's column 4, rows 0..2), one of them on another corner of A: 2 votes
    # against 1 conflict is not outvoted; with all three in place it links.
    part = (B.ab[:, 1] < 1) | ((B.ab[:, 1] == 1) & (B.ab[:, 0] <= 4))
    P = Lattice(B.xy[part], B.ab[part], B.filled[part])
    assert lattice_link(A, P, 1.0)[2] == 0
    xy3 = P.xy.copy()
    xy3[(P.ab == [3, 1]).all(1)] = A.xy[A.where[(4, 6)]]  # A's (4, 1) moved onto A's (4, 6)
    assert lattice_link(A, Lattice(xy3, P.ab, P.filled), 1.0) is None


def test_unread_tags_keep_their_corners_only_beside_a_firm_tag():
    """Tag cell (0, 0) matches its code surely; the lattice goes on to corners of tags that were
    not read (not all their corners there). The corners of the tags beside it (sharing a side)
    keep their ids; those of the diagonal tag (2, 2), sharing only a corner, do not, nor does the
    tag beyond (no fringe rule since 2026-12-08: it changed no corner of the kept
    AprilGrid sets)."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    img, c = tag_image(14, 40, 0.5)
    look = look_at_tag(img, c, 0.3, sharpen=TagConfig().sharpen)
    tag, turn, ham = decode_bits(look.white)
    cell = TagCell((0, 0), look, tag, turn, ham, True, 40.0)
    ab = np.array([[0, 0], [1, 0], [1, 1], [0, 1], [2, 0], [2, 1], [2, 2], [1, 2], [0, 2], [3, 0], [3, 1], [3, 2]])
    lat = Lattice(_board_lattice(ab), ab, np.zeros(len(ab), bool))
    offset = _offset_putting(g, 14, turn)
    under = tag_under(np.array([cell.cell]), turn, offset, g)
    keep = verified_corners(lat, [cell], under, turn, g, TagConfig(lend_depth=1))
    own = [0, 1, 2, 3]
    side = [4, 5, 7, 8, 9, 10]  # corners of tags (2, 0) and (0, 2): beside the firm tag
    assert keep[own].all() and keep[side].all() and not keep[6] and not keep[11]


def test_unread_tags_lend_ids_along_a_row_up_to_lend_depth():
    """A row of tags: the first read and matched surely, the next four too small to read. Their
    ids come through the lattice up to ``lend_depth`` tags from the read one; a tag that was read
    and did not match (a slip, a misprint) passes nothing on."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    img, c = tag_image(14, 40, 0.5)
    look = look_at_tag(img, c, 0.3, sharpen=TagConfig().sharpen)
    tag, turn, ham = decode_bits(look.white)
    a, b = np.meshgrid(np.arange(10), np.arange(2))
    ab = np.stack([a.ravel(), b.ravel()], 1)
    lat = Lattice(_board_lattice(ab), ab, np.zeros(len(ab), bool))
    first = TagCell((0, 0), look, tag, turn, ham, True, 40.0)
    offset = _offset_putting(g, 14, turn)
    tag_of = ab[:, 0] // 2  # 0 .. 4 along the row
    under = tag_under(np.array([(0, 0)]), turn, offset, g)
    for depth, reach in ((1, 1), (3, 3), (4, 4)):
        keep = verified_corners(lat, [first], under, turn, g, TagConfig(lend_depth=depth))
        np.testing.assert_array_equal(keep, tag_of <= reach)
    # Tag 2 of the row read, and its code is not the one the placement puts there: nothing beyond it.
    wrong = TagCell((4, 0), look, tag, turn, ham, True, 40.0)  # tag 14's read where another tag is
    cells = [first, wrong]
    under = tag_under(np.array([(0, 0), (4, 0)]), turn, offset, g)
    assert under[1] != 14
    keep = verified_corners(lat, cells, under, turn, g, TagConfig(lend_depth=4))
    np.testing.assert_array_equal(keep, tag_of <= 1)


def test_consistent_boards_keep_agreeing_lattices_and_drop_clashing_ones():
    """Placed lattices, surest first: one that agrees with the surest (same ids at the same places,
    new ones elsewhere) is kept; one that puts another id on a place already held (a slip) and one
    that puts a held id elsewhere (a second board) are dropped."""

    def board(ids, xy, margin, decoded=0):
        ids, xy = np.array(ids), np.array(xy, float)
        lat = Lattice(xy, np.stack([np.arange(len(ids)), np.zeros(len(ids), int)], 1), np.zeros(len(ids), bool))
        return _Board(lat, ids, Placement(0, np.zeros(2, int), margin, margin, 1), [None] * decoded, [])

    sure = board([0, 1, 2], [[10, 10], [40, 10], [70, 10]], 300.0, decoded=2)
    agree = board([2, 3], [[70.5, 10], [100, 10]], 80.0, decoded=1)
    slip = board([4, 5], [[40.3, 10.2], [200, 10]], 60.0, decoded=1)  # id 4 where id 1 is
    second = board([0, 6], [[500, 300], [530, 300]], 40.0, decoded=3)  # id 0 far from id 0
    kept, lost = consistent_boards([second, slip, agree, sure])
    assert kept == [sure, agree]
    assert lost == [slip, second]


def test_frames_without_junctions_give_nothing():
    """A uniform frame and one with a single blob have fewer than two saddle candidates: no
    corners, no error."""
    g = make_target(TargetConfig(kind="aprilgrid"))
    flat = np.full((200, 300), 0.5, np.float32)
    blob = flat.copy()
    cv2.circle(blob, (150, 100), 20, 0.1, -1)
    for img in (flat, blob):
        res = tag_pass(img, g)
        assert len(res.ids) == 0 and res.xy.shape == (0, 2)


def test_side_points_lie_on_a_flat_tags_sides():
    """On a flat tag 40 px across, the points found on its sides lie on the straight lines between
    its corners within 0.1 px, five on every side."""
    img, c = tag_image(5, 40, 0.7)
    look = tag_map(c)
    q, side = side_points(img, look, 0.3, 0.15, 0.85)
    assert np.bincount(side, minlength=4).tolist() == [5, 5, 5, 5]
    for k in range(4):
        a, b = c[k], c[(k + 1) % 4]  # side k of SIDES runs from corner k to corner k + 1
        d = b - a
        off = ((q[side == k] - a) @ np.array([-d[1], d[0]])) / np.linalg.norm(d)
        assert np.abs(off).max() < 0.1


def bowed(img: np.ndarray, corners: np.ndarray, bow: float) -> np.ndarray:
    """``img`` with every column moved down by ``bow`` * 4 s (1 - s) px, s the column's position
    between the tag's left and right sides (0 .. 1): a tag whose top and bottom sides the lens bends."""
    h, w = img.shape
    x, y = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    s = (x - corners[0, 0]) / (corners[1, 0] - corners[0, 0])
    return cv2.remap(img, x, (y - bow * 4 * s * (1 - s)).astype(np.float32), cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def test_a_bent_tag_reads_through_its_sides():
    """A tag 40 px across whose sides bow by 6 px (1.5 data cells) at their middle: through its
    corners' homography alone the data cells are read a cell and a half off and the tag does not
    decode; bent to its sides as the image shows them, it reads as itself without a bit error."""
    cfg = TagConfig()
    for t in (3, 17, 30):
        img, c = tag_image(t, 40, 0.5)
        img = np.pad(img, 10, mode="edge")
        c = c + 10
        img = bowed(img, c, 6.0)
        tid, _, ham = decode_bits(look_at_tag(img, c, 0.3, sharpen=cfg.sharpen).white)
        assert not (tid == t and ham <= cfg.max_hamming)
        tid, _, ham = decode_bits(look_at_tag(img, c, 0.3, sharpen=cfg.sharpen, max_side_misfit=cfg.max_side_misfit).white)
        assert (tid, ham) == (t, 0)


def test_sides_disagreeing_with_a_slid_corner_are_not_used():
    """A corner slid 0.3 of a tag along the diagonal (onto a data junction) leaves the sides found
    in the image far from the map its corners give: the misfit exceeds the detector's bound, where
    the true corners fit their sides within a hundredth of the tag."""
    img, c = tag_image(9, 40, 0.5)
    for corners, low in ((c, True), (c + np.array([[12.0, 12.0], [0, 0], [0, 0], [0, 0]]), False)):
        look = tag_map(corners)
        q, side = side_points(img, look, 0.3, 0.15, 0.85)
        misfit = tag_map(corners, side_px=q, side_of=side).misfit
        assert (misfit < 0.01) if low else (misfit > TagConfig().max_side_misfit)


def test_a_fringe_corner_reads_its_rays_at_its_neighbours_gap():
    """A board seen at a grazing angle (tag rows squashed): a lattice corner at the end of a row,
    with one tag side to its only neighbour, would read its rays on a circle sized by that side
    (its own gap estimate); the circle reaches into the tag and finds no four rays. Taking the
    gap of its lattice neighbours, whose steps across the rows show the squash, it passes."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 150, [c[0] + 0.02, c[1] - 0.6, 0.2], c)
    grey = cv2.GaussianBlur(img.astype(np.float32) / 255, (0, 0), 0.7)
    cfg, C = TagConfig(), 2 * g.tc
    for row in (2, 4, 6, 8):
        ab = [(a, b) for b in (row, row + 1) for a in range(7)] + [(7, row)]  # two rows, and one corner beyond
        idx = np.array([b * C + a for a, b in ab])
        assert vis[idx].all()
        own_gap = np.linalg.norm(q[idx[-1]] - q[idx[6]]) * g.cfg.tag_spacing  # its only step is a tag side
        assert np.isnan(corner_rays(grey, q[idx[-1:]].astype(np.float64), np.array([cfg.complete.ray_radius * own_gap]))).all()
        ok = rays_agree(Lattice(q[idx].astype(np.float64), np.array(ab), np.zeros(len(idx), bool)), grey, g.cfg.tag_spacing, cfg)
        assert ok[-1]


def test_candidates_of_small_tags_pass_the_looser_symmetry_test():
    """Tags about 9 px across (crossing squares under 3 px, inside the smallest fit window): with
    the tag pass's candidate symmetry test over 90 % of the corners are candidates, with the grid
    pass's stricter one (checkerboard X-junctions are symmetric over the whole window) under 75 %."""
    from cotrain.detect.saddle import outside_circle
    from cotrain.detect.tag_candidates import tag_candidates

    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = centre(g)
    img, q, vis, _ = render(g, "kb4", 180, [c[0] + 0.05, c[1] - 0.04, 1.5], c)
    assert 8 < np.linalg.norm(q[1] - q[0]) < 10 and vis.all()
    grey = img.astype(np.float32) / 255
    allowed = ~outside_circle(grey)
    allowed[[0, -1], :] = False
    allowed[:, [0, -1]] = False
    rim = cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)

    def found(cfg: TagConfig) -> float:
        xy, _ = tag_candidates(grey, allowed, cfg, {}, rim)
        return float((cKDTree(xy).query(q)[0] < 1.0).mean())

    assert TagConfig().complete.min_symmetry < TagConfig().grid.min_symmetry
    assert found(TagConfig()) > 0.9
    assert found(TagConfig(complete=replace(TagConfig().complete, min_symmetry=TagConfig().grid.min_symmetry))) < 0.75


def test_a_views_side_thread_reads_what_one_thread_reads():
    """A view's whole-image work (the distance to the rim, the saddle response, the fit windows'
    blurs) runs partly on a second thread where OpenCV may use two: the candidates, their rays,
    the distance to the rim and every blur are those of the one-thread reading, to the bit."""
    from cotrain.detect.saddle import outside_circle
    from cotrain.detect.tag_candidates import _candidates_of

    g = make_target(TargetConfig(kind="aprilgrid"))
    c = centre(g)
    img, _, vis, _ = render(g, "ds", 220, [c[0] + 0.1, c[1] - 0.05, 0.4], c)
    assert vis.sum() > 50
    grey = img.astype(np.float32) / 255
    allowed = ~outside_circle(grey)
    threads = cv2.getNumThreads()
    try:
        cv2.setNumThreads(1)
        one = _candidates_of(grey, allowed, TagConfig())
        cv2.setNumThreads(2)
        two = _candidates_of(grey, allowed, TagConfig())
    finally:
        cv2.setNumThreads(threads)
    assert len(one.xy) > 50
    np.testing.assert_array_equal(one.xy, two.xy)
    np.testing.assert_array_equal(one.rays, two.rays)
    np.testing.assert_array_equal(one.rim_dist, two.rim_dist)
    assert set(one.smoothed) <= set(two.smoothed)
    for h, blurred in one.smoothed.items():
        np.testing.assert_array_equal(blurred, two.smoothed[h])


def test_detect_files_runs_the_tag_pass_in_processes_with_the_same_output(tmp_path, worker_pools, monkeypatch):
    """``detect_files`` over AprilGrid renders and one file that is no image: in two worker
    processes the detection JSON is the same as in this process, entry for entry and in the
    files' order; the bad file is an entry with its error, and the corners are found."""
    from cotrain.io.detections import detect_files

    g = make_target(TargetConfig(kind="aprilgrid"))
    c = centre(g)
    files = []
    for k, (model, fov, dx) in enumerate([("kb4", 200, 0.0), ("ds", 220, 0.1), ("ucm", 190, -0.1), ("eucm", 210, 0.05)]):
        img, _, vis, _ = render(g, model, fov, [c[0] + dx, c[1] - 0.05, 0.35], c, seed=k)
        assert vis.sum() > 50
        for copy in range(2):
            files.append(tmp_path / f"view{k}_{copy}.png")
            cv2.imwrite(str(files[-1]), img)
    (tmp_path / "broken.png").write_bytes(b"not an image")
    files.insert(3, tmp_path / "broken.png")
    monkeypatch.setattr(Detector, "files_per_worker_tags", 4)  # a pool for these few files
    det = Detector(target=g)
    serial = detect_files(files, det, progress=False, workers=1)
    parallel = detect_files(files, det, progress=False, workers=2)
    assert worker_pools == [2]  # the files went to two worker processes
    assert parallel == serial
    assert [e["path"] for e in parallel["images"]] == [str(f) for f in files]
    assert parallel["images"][3]["error"] and not parallel["images"][3]["corners"]
    assert all(len(e["corners"]) > 50 for i, e in enumerate(parallel["images"]) if i != 3)


class _Unpicklable(Detector):
    """A detector that cannot be made in a worker process (its copy fails to unpickle there)."""

    def __setstate__(self, state):
        raise RuntimeError("no detector in this process")


def test_a_dead_worker_process_is_a_one_line_error(tmp_path, monkeypatch):
    """A worker process that cannot start stops ``detect_files`` with a ChildProcessError (an
    OSError: the commands print it as one line), not a traceback of the process pool."""
    from cotrain.io.detections import detect_files

    files = []
    for k in range(8):
        files.append(tmp_path / f"blank{k}.png")
        cv2.imwrite(str(files[-1]), np.full((64, 64), 128, np.uint8))
    monkeypatch.setattr(Detector, "files_per_worker_tags", 4)  # a pool for these few files
    with pytest.raises(ChildProcessError, match="--workers 1"):
        detect_files(files, _Unpicklable(target=make_target(TargetConfig(kind="aprilgrid"))), progress=False, workers=2)


def test_tags_read_together_read_as_each_alone():
    """The batched read (:func:`look_at_tags`, one pass over all tags of a lattice) gives every tag
    what it gets read alone: the same cells, threshold, contrast and cleanliness, with lattice
    corners around the tags (of varying number) and their sides bending the maps; a tag whose
    samples leave the image is None in both. Tags of a board seen obliquely through a fisheye."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "ds", 200, (c + [0.1, -0.05, 0.3]).tolist(), (c + [-0.3, 0.1, 0.0]).tolist())
    grey = img.astype(np.float32) / 255
    corners, unit_more, more = [], [], []
    for t in range(g.n_tags):
        k = g.tag_corners(t)
        if not vis[k].all():
            continue
        corners.append(q[k])
        # A varying number of "ring" points: the neighbouring tag's corners where seen.
        nb = g.tag_corners(t + 1) if t + 1 < g.n_tags and (t + 1) % g.cfg.tag_cols else np.zeros(0, int)
        nb = nb[vis[nb]][: t % 4 + 1]
        unit_more.append(np.array([[1 + 0.3, 0.0], [2 + 0.3, 0.0], [2 + 0.3, 1.0], [1 + 0.3, 1.0]])[: len(nb)])
        more.append(q[nb].reshape(-1, 2))
    corners.append(np.array([[-20.0, 5.0], [10.0, 5.0], [10.0, 30.0], [-20.0, 30.0]]))  # off the image
    unit_more.append(np.zeros((0, 2)))
    more.append(np.zeros((0, 2)))
    assert len(corners) > 12
    cfg = TagConfig()
    together = look_at_tags(grey, np.array(corners), 0.3, unit_more, more, sharpen=cfg.sharpen, max_side_misfit=cfg.max_side_misfit)
    for k, got in enumerate(together):
        alone = look_at_tag(grey, corners[k], 0.3, unit_more[k], more[k], sharpen=cfg.sharpen, max_side_misfit=cfg.max_side_misfit)
        assert (got is None) == (alone is None)
        if got is not None:
            np.testing.assert_allclose(got.soft, alone.soft, atol=1e-9)
            assert abs(got.threshold - alone.threshold) < 1e-9 and abs(got.contrast - alone.contrast) < 1e-9 and got.clean == alone.clean
    assert together[-1] is None and sum(x is not None for x in together) > 12


def test_decode_many_finds_the_nearest_code_in_any_turn():
    """Against a brute-force search: random data cells and codes with 0-5 flipped bits in each of
    the four turns; the nearest code, its turn and its distance (ties: first turn, lowest id)."""
    rng = np.random.default_rng(3)
    codes = printed_bits(N_CODES).reshape(N_CODES, -1).astype(bool)  # page order, True white
    rows = [rng.random(36) < 0.5 for _ in range(20)]
    for k in range(20):
        white = codes[rng.integers(N_CODES)].copy()
        white[rng.choice(36, k % 6, replace=False)] ^= True
        m = k % 4
        rows.append(white[_turn_index()[m]])  # page -> lattice order under turn m
    got = decode_many(np.array(rows))
    for white, (tag, turn, ham) in zip(rows, got):
        page = [page_order(np.where(white, 1, -1), m) > 0 for m in range(4)]
        best = min((int((codes[t] != page[m]).sum()), m, t) for m in range(4) for t in range(N_CODES))
        assert (ham, turn, tag) == best
        assert decode_bits(white) == (tag, turn, ham)


def test_the_pass_on_the_image_circle_finds_what_it_finds_on_the_whole_frame():
    """tag_pass works on the image circle's bounding box (grown by CIRCLE_PAD_PX): the same
    corners and ids as on the whole frame (read through the same lens, in the whole frame's
    pixels), at the same positions (to float rounding), in frame pixels. The board lies at the
    circle's left rim, where the crop's edge is nearest."""
    from cotrain.detect.image_circle import EquidistantLens, fit_image_circle
    from cotrain.detect.images import to_grey_float
    from cotrain.detect.saddle import outside_circle
    from cotrain.detect.tag_config import TagConfig
    from cotrain.detect.tag_pass import CIRCLE_PAD_PX, _tag_pass_in, tag_pass

    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "kb4", 200, (c + [0.0, 0.0, 0.28]).tolist(), (c + [0.5, 0.05, 0.0]).tolist())
    grey = to_grey_float(img)
    allowed = ~outside_circle(grey)
    allowed[[0, -1], :] = False
    allowed[:, [0, -1]] = False
    xs = np.nonzero(allowed.any(0))[0]
    assert xs[0] > CIRCLE_PAD_PX and xs[-1] < img.shape[1] - 1 - CIRCLE_PAD_PX  # the crop cuts the frame
    cropped = tag_pass(grey, g)
    circle = fit_image_circle(outside_circle(grey))
    whole = _tag_pass_in(grey, allowed, g, TagConfig(), EquidistantLens.from_circle(*circle, GridConfig().lens_fov))
    assert len(whole.ids) > 20
    np.testing.assert_array_equal(cropped.ids, whole.ids)
    np.testing.assert_allclose(cropped.xy, whole.xy, atol=1e-3)  # float32 sampling at other coordinates
    assert sorted(cropped.tags.tolist()) == sorted(whole.tags.tolist())
    check_ids(cropped, q, vis)


def test_a_board_whose_corners_all_fail_their_final_fit_gives_an_empty_result(monkeypatch):
    """The board is placed, but no corner passes its final fit (a frame blurred beyond the fit
    windows): no corners, with positions of shape (0, 2) in frame pixels (the crop's offset adds)."""
    import cotrain.detect.tag_pass as tp

    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = centre(g)
    img, *_ = render(g, "kb4", 200, [c[0] + 0.02, c[1] - 0.03, 0.45], c)
    monkeypatch.setattr(tp, "final_fits", lambda sub, *a, **k: (sub.xy, np.zeros(len(sub.xy), bool)))
    r = tp.tag_pass(img.astype(np.float32) / 255, g, tp.TagConfig(keep_unfitted_px=0.0))
    assert len(r.tags) > 0  # the board was read
    assert r.ids.shape == (0,) and r.xy.shape == (0, 2)


def test_small_frames_are_read_enlarged_with_positions_in_frame_pixels():
    """A frame whose shorter side is under min_side_px is read enlarged (bilinear, at most
    max_enlarge): a 640x480 fisheye view of tags 10-11 px across is read at 1.5x, every corner it
    reports keeps its own id and lies within 0.3 px of its label in the frame's own pixels."""
    from cotrain.detect.tag_config import TagConfig
    from cotrain.detect.tag_pass import enlargement, tag_pass

    cfg = TagConfig()
    assert enlargement((480, 640), cfg) == 1.5
    assert enlargement((512, 512), cfg) == pytest.approx(720 / 512)
    assert enlargement((720, 1280), cfg) == 1.0 and enlargement((800, 848), cfg) == 1.0
    assert enlargement((240, 320), cfg) == cfg.max_enlarge  # capped
    assert enlargement((480, 640), TagConfig(min_side_px=0)) == 1.0

    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "kb4", 200, (c + [0.0, 0.0, 1.1]).tolist(), (c + [0.0, 0.05, 0.0]).tolist(), size=(640, 480))
    assert np.linalg.norm(q[1] - q[0]) < 12  # small tags
    r = tag_pass(img.astype(np.float32) / 255, g)
    assert r.scale == 1.5
    check_ids(r, q, vis, tol=0.3)
    assert len(r.ids) >= 0.95 * vis.sum()


def test_a_blurred_view_is_read_at_half_resolution_too():
    """A 200-degree view blurred by a Gaussian of 2.5 px, where the full-resolution pass alone
    (completion by saddle fits at the print's full contrast only) finds under half the corners:
    with the half-resolution pass the result is a superset holding most visible corners, each at
    its own label (fitted again at full resolution). Completion that moves the print onto the
    image where the fits fail (``print_fit``), or that fits the saddles the blur has left faint
    with a threshold scaled to their contrast (``dim_gaps``), finds more at full
    resolution alone, each at its own label too."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    c = np.array(centre(g))
    img, q, vis, _ = render(g, "kb4", 200, (c + [0.0, 0.0, 0.5]).tolist(), c.tolist())
    grey = cv2.GaussianBlur(img.astype(np.float32) / 255, (0, 0), 2.5)
    saddles = replace(TagConfig().complete, print_fit_gap_px=0.0, print_fit_rim_px=0.0, dim_gaps=0.0)
    alone = tag_pass(grey, g, TagConfig(half_resolution=False, complete=saddles))
    both = tag_pass(grey, g, TagConfig(complete=saddles))
    assert 2 * len(alone.ids) < g.n_corners
    assert set(alone.ids.tolist()) <= set(both.ids.tolist())
    assert len(both.ids) > 0.8 * vis.sum()
    err = check_ids(both, q, vis, tol=1.5)
    assert np.median(err) < 0.3
    faint = tag_pass(grey, g, TagConfig(half_resolution=False, complete=replace(saddles, dim_gaps=1.0)))
    assert len(faint.ids) > 0.8 * vis.sum()
    err = check_ids(faint, q, vis, tol=1.5)
    assert np.median(err) < 0.3
    printed = tag_pass(grey, g, TagConfig(half_resolution=False, complete=replace(TagConfig().complete, dim_gaps=0.0)))
    assert len(printed.ids) > len(alone.ids) + 20
    err = check_ids(printed, q, vis, tol=1.5)
    assert np.median(err) < 0.3


@pytest.mark.parametrize("size, centre, radius, scale", [((480, 640), (330, 236), 226, 1.5), ((720, 1280), (655, 362), 350, 1.0)])
def test_a_views_lens_in_the_frames_pixels_is_the_frames_image_circle(size, centre, radius, scale):
    """A frame is read cropped to its image circle (a 640x480 one enlarged 1.5x first): the view's
    lens is in the crop's pixels; frame_lens() is centred on the circle drawn in the frame and
    spans its radius with the guessed FoV, and maps every ray to the crop lens's image point
    taken back to the frame (x_frame = (x_crop + origin + 0.5) / f - 0.5)."""
    grey = np.zeros(size, np.float32)
    cv2.circle(grey, centre, radius, 0.6, -1)
    view = _view_of(grey, TagConfig())
    assert view.scale == scale and view.lens is not None and view.origin != (0, 0)
    lens = view.frame_lens()
    assert np.allclose(lens.centre, centre, atol=1.5)
    assert np.isclose(lens.focal * np.radians(GridConfig().lens_fov / 2), radius, rtol=0.02)
    v = np.array([[0.0, 0.0, 1.0], [0.6, 0.1, 0.79], [-0.9, 0.3, -0.2], [0.2, -0.95, 0.1]])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    q_frame = (view.lens.project(v) + np.array(view.origin) + 0.5) / view.scale - 0.5
    assert np.allclose(lens.project(v), q_frame, atol=1e-9)
