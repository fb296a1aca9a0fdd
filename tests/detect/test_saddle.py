"""Saddle fitting (cotrain.detect.saddle) on hand-made X-junctions, L-corners, edges and rim cuts."""

import cv2
import numpy as np
import pytest
from scipy.ndimage import map_coordinates

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.saddle import MIN_CONTRAST_SCALE, contrast_scale, fit_saddles, local_contrast, pixel_index, saddle_fit, smooth_for


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


def _reference_fit(
    sm: np.ndarray, q0: np.ndarray, half: int, cfg: GridConfig, rim_dist: np.ndarray | None
) -> tuple[bool, np.ndarray, np.ndarray]:
    """saddle_fit's contract for one point, written independently of its compiled kernel: windows
    sampled by scipy's map_coordinates, the weighted quadratic solved by LAPACK's least squares,
    the saddle's directions from numpy's eigh. Returns ok, the saddle (2,), its axes (2, 2)."""
    n = 2 * half + 1
    g = np.arange(n) - half
    gx, gy = np.meshgrid(g, g)
    gx, gy = gx.ravel().astype(float), gy.ravel().astype(float)
    A = np.stack([gx * gx, gx * gy, gy * gy, gx, gy, np.ones_like(gx)], 1)
    w = np.exp(-(gx**2 + gy**2) / (2 * (0.6 * half) ** 2))
    reach = 1 + 0.8 * half

    def fit(x: float, y: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, bool]:
        patch = map_coordinates(sm.astype(float), [y + gy, x + gx], order=1, mode="nearest")
        valid = np.ones_like(patch)
        if rim_dist is not None:
            near = rim_dist[min(max(round(y), 0), sm.shape[0] - 1), min(max(round(x), 0), sm.shape[1] - 1)] < reach + 1.5 * half + 1
            if near:
                valid = (map_coordinates(rim_dist.astype(float), [y + gy, x + gx], order=1, mode="constant", cval=0.0) > reach) * 1.0
        # Weights: w^2 over a whole window (the design matrix pinv(w A) w), w where part of it is
        # masked (A^T diag(w valid) A): two Gaussians, as the fit has always had them.
        sw = w if valid.all() else np.sqrt(w * valid)
        coef = np.linalg.lstsq(A * sw[:, None], patch * sw, rcond=None)[0]
        return coef, patch, valid, (w * valid).sum() >= 0.5 * w.sum()

    x, y = q0
    for _ in range(4):
        (a, b, c, d, e, _), _, _, posed = fit(x, y)
        det = 4 * a * c - b * b
        if det >= 0 or not posed:
            return False, q0, np.zeros((2, 2))
        step = -np.array([2 * c * d - b * e, -b * d + 2 * a * e]) / det
        if np.hypot(*step) > half:
            return False, q0, np.zeros((2, 2))
        x, y = x + step[0], y + step[1]
    H, W = sm.shape
    if rim_dist is None:
        inside = half <= x < W - 1 - half and half <= y < H - 1 - half
    else:
        inside = 0 <= x <= W - 1 and 0 <= y <= H - 1 and rim_dist[round(y), round(x)] >= cfg.min_rim_px
    if not inside or np.hypot(x - q0[0], y - q0[1]) > half:
        return False, q0, np.zeros((2, 2))
    (a, b, c, *_), patch, valid, posed = fit(x, y)
    pair = valid * valid[::-1]
    z = patch - (patch * valid).sum() / max(valid.sum(), 1)
    sym = (z * z[::-1] * pair).sum() >= cfg.min_symmetry * max(
        (z * z * pair).sum(), 1e-12
    ) and pair.sum() >= cfg.min_symmetric_share * n * n
    lam, vec = np.linalg.eigh([[a, b / 2], [b / 2, c]])
    neg, pos = -lam[0], lam[1]
    big = max(neg, pos, 1e-12)
    good = (
        posed
        and sym
        and neg > 0
        and pos > 0
        and big * half * half >= cfg.min_saddle_contrast
        and min(neg, pos) / big >= cfg.min_saddle_ratio
    )
    if not good:
        return False, q0, np.zeros((2, 2))
    t = np.arctan(np.sqrt(pos / neg))
    axes = np.stack([np.cos(t) * vec[:, 1] + np.sin(t) * vec[:, 0], np.cos(t) * vec[:, 1] - np.sin(t) * vec[:, 0]])
    return True, np.array([x, y]), axes


def test_saddle_fit_equals_an_independent_reference():
    """The compiled fit against :func:`_reference_fit`, point by point and in one call: X-junctions
    in the open, cut by the rim (masked fit), at the image border, and points with no saddle
    (L-corner, flat); one point at a time (the growth) gives what a batch gives."""
    rng = np.random.default_rng(3)
    size = 61
    g = np.arange(size) - 30.0
    X, Y = np.meshgrid(g, g)
    u, v = np.cos(0.4) * X + np.sin(0.4) * Y, -np.sin(0.4) * X + np.cos(0.4) * Y
    checker = np.where((np.floor(u / 12) + np.floor(v / 12)) % 2 == 0, 0.85, 0.12).astype(np.float32)
    checker[(X > 14) & (Y > 14)] = 0.5  # a flat patch: no saddle
    allowed = np.hypot(X + 4, Y) < 27  # an image circle that cuts some junctions
    img = np.where(allowed, checker, 0.0).astype(np.float32)
    rim_dist = cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)
    corners = [
        (30 + 12 * (np.cos(0.4) * i - np.sin(0.4) * j), 30 + 12 * (np.sin(0.4) * i + np.cos(0.4) * j))
        for i in range(-3, 4)
        for j in range(-3, 4)
    ]
    pts = np.array([c for c in corners if -2 < c[0] < size + 1 and -2 < c[1] < size + 1]) + rng.uniform(-1.2, 1.2, (1, 2))
    # Flat, at the border, outside, NaN, infinite, and so far out that a pixel index would overflow.
    pts = np.concatenate([pts, [[50.0, 50.0], [1.0, 30.0], [30.0, 59.5], [-3.0, 70.0], [np.nan, 3.0], [np.inf, 3.0], [1e19, -1e19]]])
    cfg = GridConfig()
    for half in (2, 4):
        sm = smooth_for(img, half)
        for rd in (None, rim_dist):
            q, ok, axes = saddle_fit(sm, pts, half, cfg=cfg, rim_dist=rd)
            assert 3 < ok.sum() < len(pts)  # both outcomes are exercised
            for k in range(len(pts)):
                far = not (np.abs(pts[k]) < 1e9).all()
                ok_ref, q_ref, axes_ref = (False, pts[k], 0) if far else _reference_fit(sm, pts[k], half, cfg, rd)
                q1, ok1, axes1 = saddle_fit(sm, pts[k : k + 1], half, cfg=cfg, rim_dist=rd)
                assert ok1[0] == ok[k] == ok_ref
                assert np.array_equal(q1[0], q[k], equal_nan=True)
                if ok[k]:  # the same two edge directions (up to sign and order): each matches one, and both are matched
                    assert np.abs(q[k] - q_ref).max() < 1e-5
                    cos = np.abs(axes[k] @ axes_ref.T)
                    assert np.abs(cos.max(1) - 1).max() < 1e-6 and np.abs(cos.max(0) - 1).max() < 1e-6
                else:
                    assert np.array_equal(q[k], pts[k], equal_nan=True) and not axes[k].any()


def test_saddle_fit_takes_thousands_of_points_and_checks_the_rim_size():
    """A tag pass's thousands of candidates in one call (cv2.remap, which the fit once sampled
    with, refused windows of over 32767 rows), and a rim distance of another size than the image
    is an error, not a read outside it."""
    img = _x_junction(20.3, 19.65)
    sm = smooth_for(img, 5)
    pts = np.tile([[19.0, 21.0]], (4000, 1))
    xy, ok, _ = saddle_fit(sm, pts, 5)
    assert ok.all() and np.abs(xy - [20.3, 19.65]).max() < 0.05
    with pytest.raises(ValueError, match="differ in size"):
        saddle_fit(sm, pts[:1], 5, rim_dist=np.ones((10, 10), np.float32))


def test_pixel_index_rounds_clamps_and_takes_nan_without_a_warning():
    """Nearest pixels clamped into the image; a NaN point (a prediction behind the lens's
    horizon) and points far outside land on the border pixels, and no cast warning is raised."""
    import warnings

    q = np.array([[2.4, 3.6], [-5.0, 40.0], [np.nan, 3.0], [1e30, -1e30]])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = pixel_index(q, 20, 15)
    np.testing.assert_array_equal(got, [[2, 4], [0, 14], [0, 3], [19, 0]])


def test_local_contrast_is_the_5_to_95_percentile_spread_in_a_square_cut_to_the_image():
    """Over a horizontal ramp (column x holds x / 99) the square of half-size 10 around a point is
    21 columns of 21 equal values: its 5th and 95th percentiles fall in its 2nd and 20th columns,
    a spread of 18 / 99. At the image's left edge it is cut to 11 columns, and they fall in its
    first and last: 10 / 99. On a flat image the spread is 0."""
    ramp = np.tile(np.linspace(0.0, 1.0, 100, dtype=np.float32), (60, 1))
    c = local_contrast(ramp, np.array([[50.0, 30.0], [0.0, 30.0]]), np.array([10.0, 10.0]))
    np.testing.assert_allclose(c, [18 / 99, 10 / 99], rtol=1e-5)
    assert local_contrast(np.full((20, 20), 0.4, np.float32), np.array([[5.0, 5.0]]), np.array([3.0]))[0] == 0


def test_contrast_scale_is_the_share_of_the_boards_contrast_between_a_quarter_and_one():
    cfg = GridConfig(board_contrast=0.5)
    assert contrast_scale(0.2, cfg) == pytest.approx(0.4)
    assert contrast_scale(0.8, cfg) == 1.0 and contrast_scale(0.01, cfg) == MIN_CONTRAST_SCALE
    assert contrast_scale(0.01, GridConfig(board_contrast=0.0)) == 1.0  # off


def test_blurs_made_ahead_on_another_thread_are_the_blurs_made_on_demand():
    """smooth_ahead starts the crop's usual blurs on an idle thread; smooth_cached hands each over
    when asked, the same array as smooth_for makes, and makes the others on demand as before."""
    from concurrent.futures import ThreadPoolExecutor

    from cotrain.detect.saddle import smooth_ahead, smooth_cached, smooth_for

    grey = np.random.default_rng(3).random((120, 90)).astype(np.float32)
    ahead: dict = {}
    with ThreadPoolExecutor(max_workers=1) as beside:
        smooth_ahead(ahead, grey, beside)
        for half in (2, 3, 4, 5, -1, 1, 7):
            assert np.array_equal(smooth_cached(ahead, grey, half), smooth_for(grey, half))
    assert set(ahead) == {2, 3, 4, 5, -1, 1, 7} and all(isinstance(v, np.ndarray) for v in ahead.values())
