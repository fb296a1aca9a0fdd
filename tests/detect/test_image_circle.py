"""The lens guessed from the image circle (cotrain.detect.image_circle), against independent math
and against the renderer's cameras."""

import cv2
import numpy as np
import pytest

from cotrain.detect.image_circle import (
    EquidistantLens,
    PlaneMaps,
    _black_all_around,
    _consensus_circle,
    beyond_circle,
    fit_image_circle,
    frame_edge,
    local_views,
    parallelogram_corner,
    ray_homographies,
)
from cotrain.detect.saddle import black_level, half_blurred, outside_and_circle, outside_circle
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_reading import decode_bits, look_at_tag, shortest_side
from cotrain.targets import TargetConfig, make_target
from tests.detect.test_tag_pass import centre, render

UNIT = np.array([[0.0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]])


def test_equidistant_lens_known_values_and_round_trip():
    lens = EquidistantLens.from_circle(np.array([640.0, 360.0]), 400.0, 200.0)
    assert lens.focal == pytest.approx(400.0 / np.radians(100.0))
    # The circle's edge is 100 deg off-axis; the axis is the centre; 90 deg lies focal * pi / 2 out.
    v_rim = np.array([np.sin(np.radians(100)), 0.0, np.cos(np.radians(100))])
    np.testing.assert_allclose(lens.project(v_rim), [1040.0, 360.0], atol=1e-9)
    np.testing.assert_allclose(lens.project(np.array([0.0, 0.0, 2.0])), [640.0, 360.0], atol=1e-12)
    np.testing.assert_allclose(lens.project(np.array([0.0, -3.0, 0.0])), [640.0, 360.0 - lens.focal * np.pi / 2], atol=1e-9)
    # Batch shapes, rays of any length, and the round trip up to the circle's edge and beyond 90 deg.
    rng = np.random.default_rng(0)
    q = np.array([640.0, 360.0]) + rng.uniform(-390, 390, (3, 5, 2)) * [1, 0.7]
    v = lens.lift(q)
    assert v.shape == (3, 5, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(lens.project(2.5 * v), q, atol=1e-9)
    np.testing.assert_allclose(lens.lift(np.array([640.0, 360.0])), [0, 0, 1], atol=1e-12)


def test_plane_maps_to_plane_inverts_the_maps_with_and_without_a_lens():
    """Batched plane -> pixel maps (a homography each, and the same through each map's own view
    of an equidistant lens's rays, 40-100 deg off-axis): to_plane takes their pixels back to the
    plane's points (round trip to 1e-9 m), per map, with batch shapes (K, M, 2)."""
    rng = np.random.default_rng(4)
    lens = EquidistantLens.from_circle(np.array([640.0, 360.0]), 400.0, 220.0)
    K, M = 3, 20
    H = np.array([[900.0, 40.0, 300.0], [-30.0, 850.0, 200.0], [0.2, -0.1, 1.0]]) + rng.normal(0, 1, (K, 3, 3)) * [
        [40, 20, 30],
        [20, 40, 30],
        [0.1, 0.1, 0],
    ]
    p = rng.uniform(0.0, 0.3, (K, M, 2))
    flat = PlaneMaps(H)
    q = flat(p)
    assert q.shape == (K, M, 2)
    np.testing.assert_allclose(flat.to_plane(q), p, atol=1e-9)
    # Through the lens: each map's view of rays around a direction well off the axis.
    off = np.radians([40.0, 70.0, 100.0])
    z = np.stack([np.sin(off), np.zeros(K), np.cos(off)], 1)
    x = np.cross([0.0, 1.0, 0.0], z)
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    R = np.stack([x, np.cross(z, x), z], 1)
    Hv = np.array([[1.0, 0.0, -0.15], [0.0, 1.0, -0.15], [0.0, 0.0, 0.5]])[None].repeat(K, 0)  # board 0.5 m out, centred
    views = PlaneMaps(Hv, R, lens)
    q = views(p)
    assert np.isfinite(q).all() and q.shape == (K, M, 2)
    np.testing.assert_allclose(views.to_plane(q), p, atol=1e-9)


def test_parallelogram_corner_closes_the_quad_in_the_rays_own_view():
    """The fourth corner agrees with the parallelogram closed in :func:`local_views`' rotated view
    (another construction: a rotation basis, not the plane through the mean ray); it is exact for
    a parallelogram on the plane perpendicular to the mean ray; and it refuses rays too far apart."""
    lens = EquidistantLens.from_circle(np.array([640.0, 360.0]), 380.0, 210.0)
    rng = np.random.default_rng(3)
    for _ in range(30):
        q = np.array([640.0, 360.0]) + rng.uniform(-360, 360, 2) * [1, 0.9]
        q3 = q + rng.normal(0, 25, (3, 2))
        v = lens.lift(q3)
        got = parallelogram_corner(*v.tolist(), lens)
        g, R, ok = local_views(q3[None], lens)
        assert ok[0] and got is not None
        want = lens.project(np.append(g[0, 1] + g[0, 2] - g[0, 0], 1.0) @ R[0])
        np.testing.assert_allclose(got, want, atol=1e-9)
    # A square 100 deg off-axis on the plane perpendicular to the mean of three of its corners' rays.
    z = np.array([np.sin(np.radians(100)), 0.0, np.cos(np.radians(100))])
    a, b = np.array([0.0, 0.05, 0.0]), np.cross(z, [0.0, 0.05, 0.0])
    c = 0.5 * z - (a + b) / 3  # the mean of the three rays (to c, c + a, c + b) points along z
    corners = [c, c + a, c + b]
    assert np.allclose(np.cross(sum(p / np.linalg.norm(p) for p in corners), z), 0, atol=1e-3)
    got = parallelogram_corner(*[(p / np.linalg.norm(p)).tolist() for p in corners], lens)
    truth = lens.project(c + a + b)
    pixel_guess = sum(lens.project(p) * w for p, w in zip(corners, (-1, 1, 1)))
    assert np.linalg.norm(np.array(got) - truth) < 0.05 * np.linalg.norm(pixel_guess - truth)
    # Two rays 90 deg from their mean: no one view holds them.
    assert parallelogram_corner([0.0, 0, 1], [1.0, 0, 0], [-1.0, 0, 0], lens) is None


def test_ray_homographies_take_the_unit_square_to_its_rays_and_refuse_no_square():
    rng = np.random.default_rng(1)
    H_true = rng.normal(size=(40, 3, 3))
    v = np.einsum("tij,kj->tki", H_true, UNIT)
    v /= np.linalg.norm(v, axis=-1, keepdims=True)  # each corner's ray, pointing where its point lies
    H, ok = ray_homographies(v)
    assert ok.all()
    Hu = np.einsum("tij,kj->tki", H, UNIT)
    scale = (Hu * v).sum(-1)
    assert (scale > 0).all()  # positive multiples: the points in front
    np.testing.assert_allclose(Hu, scale[..., None] * v, atol=1e-9)
    # Inner points agree with the true map (up to the positive scale): a homography is fixed by four points.
    u = np.array([0.3, 0.7, 1.0])
    a, b = H @ u, H_true @ u
    a /= np.linalg.norm(a, axis=-1, keepdims=True)
    b /= np.linalg.norm(b, axis=-1, keepdims=True)
    np.testing.assert_allclose(np.abs((a * b).sum(-1)), 1.0, atol=1e-9)
    # One corner's ray reversed: no view of a square; three rays in one plane through the lens: none either.
    flipped = v.copy()
    flipped[:, 1] *= -1
    assert not ray_homographies(flipped)[1].any()
    flat = v[:1].copy()
    flat[0, 3] = flat[0, 0] + flat[0, 1]
    assert not ray_homographies(flat)[1].any()


def circle_frame(h: int, w: int, c: tuple[float, float], r: float, dark_sector: float = 0.0, noise: float = 0.0) -> np.ndarray:
    """A grey scene inside a circle of radius r about c, black outside (anti-aliased by 4x
    supersampling); with ``dark_sector`` (deg), a black part of the scene joined to the frame
    (from a third of the radius out, over that angle); with ``noise``, a black frame at 0.03 and
    Gaussian noise of that sigma over everything."""
    s = 4
    yy, xx = np.mgrid[0 : h * s, 0 : w * s]
    dx, dy = (xx + 0.5) / s - 0.5 - c[0], (yy + 0.5) / s - 0.5 - c[1]
    inside = np.hypot(dx, dy) < r
    ang = np.degrees(np.arctan2(dy, dx))
    inside &= ~((ang > 0) & (ang < dark_sector) & (np.hypot(dx, dy) > r / 3))
    img = cv2.resize(inside.astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) * 0.6
    if noise:
        img = np.maximum(img, 0.03) + np.random.default_rng(0).normal(0, noise, img.shape).astype(np.float32)
    return img


@pytest.mark.parametrize(
    "c, r, dark_sector, noise",
    [
        ((640.0, 360.0), 340.0, 0.0, 0.0),
        ((640.0, 360.0), 340.0, 30.0, 0.0),
        ((640.0, 360.0), 340.0, 90.0, 0.02),
        ((640.0, 360.0), 340.0, 150.0, 0.02),
        ((652.3, 371.8), 500.0, 0.0, 0.02),
        ((630.0, 355.0), 700.0, 0.0, 0.0),
    ],
)
def test_fit_image_circle_finds_the_circle_whole_or_cut_by_the_frame(c, r, dark_sector, noise):
    """A whole circle; with a black part of the scene joined to the frame over 30 or 90 degrees
    (the fit narrows its band onto the circle) or over 150 (too much of the edge off the circle for
    that: the circle through most edge pixels); with a noisy black frame; cut at the top and
    bottom of the frame; and larger than the frame, with only the frame's corners black: the
    centre within half a pixel, the radius within 2.5 px (the black frame is found at half
    resolution and grown by a pixel: the radius comes out 1-2 px long, under 0.5 % of the
    focal length)."""
    img = circle_frame(720, 1280, c, r, dark_sector, noise)
    fit = fit_image_circle(outside_circle(img))
    assert fit is not None
    np.testing.assert_allclose(fit[0], c, atol=0.5)
    assert fit[1] == pytest.approx(r, abs=2.5)


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_fit_image_circle_finds_a_circle_cut_by_the_frame_with_dark_scene_at_its_border(seed):
    """A circle larger than the frame (black only in its four corners), with dark scene along the
    top and bottom edges inside it (twelve discs: a dark room, as the frame's edge shows it): most
    edge pixels are the scene's, off the circle. The circle is found (centre within half a pixel,
    radius within 2.5 px). With seed 3 a single draw of circles through three edge pixels misses
    it; the second, larger draw finds it."""
    c, r = (620.4, 382.5), 655.0
    img = circle_frame(720, 1280, c, r, 0.0, 0.02)
    rng = np.random.default_rng(seed)
    for k in range(12):
        x, y = float(rng.uniform(100, 1180)), 0.0 if k % 2 == 0 else 719.0
        cv2.circle(img, (int(x), int(y)), int(rng.uniform(60, 160)), 0.0, -1)
    outside = outside_circle(img)
    fit = fit_image_circle(outside)
    assert fit is not None
    np.testing.assert_allclose(fit[0], c, atol=0.5)
    assert fit[1] == pytest.approx(r, abs=2.5)
    if seed == 3:
        first = _consensus_circle(frame_edge(outside), outside.shape)
        assert first is None or not _black_all_around(outside, *first)


def test_beyond_circle_leaves_out_dark_scene_joined_to_the_frame():
    """A dark part of the scene joined to the black frame over 90 degrees (as a board's black
    squares at the rim join it under vignetting): the frame's region reaches far into the image
    circle; beyond_circle keeps the frame beyond the fitted circle (less 2 px) and drops the
    rest, and gives the region back whole where no circle was fitted."""
    c, r = (640.0, 360.0), 340.0
    outside = outside_circle(circle_frame(720, 1280, c, r, 90.0, 0.02))
    y, x = np.mgrid[:720, :1280]
    dist = np.hypot(x - c[0], y - c[1])
    assert outside[dist < r - 20].mean() > 0.05  # the dark sector, inside the circle, counted as frame
    kept = beyond_circle(outside, fit_image_circle(outside))
    assert not kept[dist < r - 3].any()  # nothing inside the circle
    np.testing.assert_array_equal(kept[dist > r + 3], outside[dist > r + 3])  # the frame as it was
    assert kept[dist > r + 3].mean() > 0.99
    assert beyond_circle(outside, None) is outside


@pytest.mark.parametrize("noise", [0.0, 0.004])
def test_a_lifted_black_frame_is_still_the_frame(noise):
    """A camera whose black is 16/255 (the whole image lifted and compressed to 16-255): the black
    frame's level is measured from the image's border, the circle found as in a zero-black frame,
    and a dark square beside the rim (0.05 over the lifted black) is not taken for the frame."""
    c, r = (640.0, 360.0), 340.0
    img = circle_frame(720, 1280, c, r, 0.0, 0.0)
    yy, xx = np.mgrid[0:720, 0:1280]
    img[(np.abs(xx - 320) < 20) & (np.abs(yy - 360) < 20)] = 0.05  # a dark square touching the rim at x = 300
    lifted = (img * (239 / 255) + 16 / 255 + np.random.default_rng(3).normal(0, noise, img.shape)).astype(np.float32)
    assert black_level(half_blurred(lifted)) == pytest.approx(16 / 255, abs=0.01)
    outside = outside_circle(lifted)
    assert not outside[360, 320]  # the dark square, inside the circle
    fit = fit_image_circle(outside)
    assert fit is not None
    np.testing.assert_allclose(fit[0], c, atol=0.5)
    assert fit[1] == pytest.approx(r, abs=2.5)


def test_outside_and_circle_is_the_region_and_its_fit():
    """outside_and_circle gives what outside_circle and fit_image_circle give apart, with one fit:
    a zero-black frame with dark scene joined to it, a camera's lifted black, and a full frame
    (no circle)."""
    c, r = (640.0, 360.0), 340.0
    plain = circle_frame(720, 1280, c, r, 90.0, 0.02)
    lifted = (circle_frame(720, 1280, c, r) * (239 / 255) + 16 / 255).astype(np.float32)
    full = np.full((720, 1280), 0.4, np.float32)
    for img in (plain, lifted, full):
        outside, circle = outside_and_circle(img)
        np.testing.assert_array_equal(outside, outside_circle(img))
        fit = fit_image_circle(outside)
        assert (circle is None) == (fit is None)
        if fit is not None:
            np.testing.assert_allclose(circle[0], fit[0], atol=1e-9)
            assert circle[1] == pytest.approx(fit[1], abs=1e-9)
            np.testing.assert_allclose(circle[0], c, atol=0.5)
    assert outside_and_circle(full)[1] is None and outside_and_circle(plain)[1] is not None


def test_black_level_is_zero_without_a_flat_dark_border():
    """A full-frame image: a mid-grey border, a dark but varied one (a room): level 0."""
    rng = np.random.default_rng(4)
    assert black_level(np.full((360, 640), 0.3, np.float32)) == 0.0
    assert black_level(rng.uniform(0.05, 0.4, (360, 640)).astype(np.float32)) == 0.0


def test_a_dim_wall_at_the_border_is_no_black_frame():
    """A full-frame image whose border is a dim, smooth wall (0.06-0.14, flat enough to read as a
    lifted black level) beside a board's dark square at 0.08: what the lifted threshold finds
    outlines no image circle, so nothing is marked outside."""
    yy, xx = np.mgrid[0:720, 0:1280]
    img = (0.06 + 0.08 * xx / 1280).astype(np.float32)
    img[300:400, 500:600] = 0.08
    assert black_level(half_blurred(img)) > 0.03
    assert not outside_circle(img).any()


def test_zero_black_frames_keep_the_fixed_threshold():
    """A noisy black frame at zero: the same mask as dark regions under 0.04 touching the border,
    worked out here with scipy's labelling instead of OpenCV's."""
    from scipy import ndimage

    img = circle_frame(720, 1280, (640.0, 360.0), 340.0, 90.0, 0.02)
    low = half_blurred(img) < 0.04
    lab, _ = ndimage.label(low)
    touching = np.setdiff1d(np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]])), [0])
    expected = cv2.resize(np.isin(lab, touching).astype(np.uint8), (1280, 720), interpolation=cv2.INTER_NEAREST)
    expected = cv2.dilate(expected, np.ones((3, 3), np.uint8)) > 0
    np.testing.assert_array_equal(outside_circle(img), expected)


def test_fit_image_circle_refuses_frames_without_a_black_circle():
    """No black frame; a dark scene at the frame's edge (a straight edge); a dark disc cut by the
    frame's edge (a round edge of 700 px, but the scene beyond it is not black all around): no
    circle, so tags are read through pixel homographies."""
    rng = np.random.default_rng(2)
    grey = np.full((480, 640), 0.5, np.float32)
    assert fit_image_circle(outside_circle(grey)) is None
    dark = grey.copy()
    dark[:, :200] = 0.0
    dark += rng.normal(0, 0.01, dark.shape).astype(np.float32)
    assert fit_image_circle(outside_circle(dark)) is None
    yy, xx = np.mgrid[0:480, 0:640]
    disc = np.where(np.hypot(xx - 100.0, yy - 240.0) < 150, 0.0, 0.5).astype(np.float32)
    disc += rng.normal(0, 0.01, disc.shape).astype(np.float32)
    assert fit_image_circle(outside_circle(disc)) is None


def test_large_bent_tags_read_through_the_guessed_lens():
    """A board 8 cm from a 200-degree lens of each family, 40-90 deg off-axis: tags 30-110 px
    across whose sides the lens bends. Read from their true corners through the equidistant lens
    guessed from the image circle (taken as 210 degrees, not the true 200), every one decodes as
    itself; through the corners' pixel homography bent to its sides, at least four of them (the
    largest, 100 px and more, and the farthest off-axis) do not."""
    missed = 0
    for model in ("kb4", "ucm", "eucm", "ds"):
        missed += _large_tags_read(model)
    assert missed >= 4


def _large_tags_read(model: str) -> int:
    """The tags of 30 px and more that the pixel homography misses (all must read through the lens)."""
    g = make_target(TargetConfig(kind="aprilgrid", margin=0.3))
    cfg = TagConfig()
    c = np.array(centre(g))
    img, q, vis, _ = render(g, model, 200, (c + [0, 0, 0.08]).tolist(), (c + [-0.5, 0.05, 0]).tolist())
    grey = img.astype(np.float32) / 255
    circle = fit_image_circle(outside_circle(grey))
    assert circle is not None
    np.testing.assert_allclose(circle[0], [640, 360], atol=1.0)  # the renderer's circle: 380 px about the centre
    assert circle[1] == pytest.approx(380, abs=2.0)
    lens = EquidistantLens.from_circle(circle[0], circle[1], cfg.grid.lens_fov)
    through_lens, through_pixels, n = 0, 0, 0
    for t in range(g.n_tags):
        corners = q[np.asarray(g.tag_corners(t))[[0, 3, 2, 1]]]  # lattice order (0, 0), (1, 0), (1, 1), (0, 1)
        if not vis[g.tag_corners(t)].all() or shortest_side(corners) < 30:
            continue
        n += 1
        for lens_or_none in (lens, None):
            look = look_at_tag(grey, corners, 0.3, sharpen=cfg.sharpen, max_side_misfit=cfg.max_side_misfit, lens=lens_or_none)
            assert look is not None  # every sample inside the image
            tid, _, ham = decode_bits(look.white)
            if tid == t and ham <= cfg.max_hamming:
                through_lens += lens_or_none is not None
                through_pixels += lens_or_none is None
    assert n >= 10
    assert through_lens == n, f"{model}: {n - through_lens} of {n} large tags not read through the lens"
    return n - through_pixels


def test_algebraic_circle_known_values_and_numpy_least_squares():
    """Points on a known circle (an arc of it, with noise) give that circle; the fit solved about
    the points' mean is numpy's least-squares solution of the (N, 3) system; points on a line,
    or fewer than three, fit no circle."""
    from cotrain.detect.image_circle import _algebraic_circle

    rng = np.random.default_rng(5)
    a = rng.uniform(0.3, 2.0, 400)
    p = np.stack([612.5 + 431.0 * np.cos(a), 355.25 + 431.0 * np.sin(a)], 1)
    centre, radius = _algebraic_circle(p)
    np.testing.assert_allclose(centre, [612.5, 355.25], atol=1e-6)
    assert radius == pytest.approx(431.0, abs=1e-6)
    noisy = p + rng.normal(0, 1.0, p.shape)
    sol = np.linalg.lstsq(np.concatenate([noisy, np.ones((len(noisy), 1))], 1), (noisy**2).sum(1), rcond=None)[0]
    c_ref = sol[:2] / 2
    centre, radius = _algebraic_circle(noisy)
    np.testing.assert_allclose(centre, c_ref, atol=1e-6)
    assert radius == pytest.approx(np.sqrt(sol[2] + c_ref @ c_ref), abs=1e-6)
    line = np.stack([np.arange(300.0), 2 * np.arange(300.0) + 5], 1)
    assert _algebraic_circle(line) is None
    assert _algebraic_circle(p[:2]) is None
