"""Saddle fitting (cotrain.detect.saddle) on hand-made X-junctions, L-corners, edges and rim cuts."""

import cv2
import numpy as np
import pytest

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.saddle import fit_saddles, saddle_fit, smooth_for


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


def test_one_point_fit_equals_the_batched_fit():
    """The lattice growth fits one spot at a time through a scalar path; it must give what the
    batched path gives for the same point: X-junctions in the open, cut by the rim (masked fit),
    at the image border, and points with no saddle (L-corner, flat)."""
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
    pts = np.concatenate([pts, [[50.0, 50.0], [1.0, 30.0], [30.0, 59.5]]])  # flat, at the border
    cfg = GridConfig()
    for half in (2, 4):
        sm = smooth_for(img, half)
        for rd in (None, rim_dist):
            q, ok, axes = saddle_fit(sm, pts, half, cfg=cfg, rim_dist=rd)
            assert 3 < ok.sum() < len(pts)  # both outcomes are exercised
            for k in range(len(pts)):
                q1, ok1, axes1 = saddle_fit(sm, pts[k : k + 1], half, cfg=cfg, rim_dist=rd)
                assert ok1[0] == ok[k]
                assert np.abs(q1[0] - q[k]).max() < 1e-3
                if ok[k]:  # the same two edge directions (up to sign and order)
                    assert np.abs(np.abs(axes1[0] @ axes[k].T).max(1) - 1).max() < 1e-4
