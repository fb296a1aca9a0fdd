"""Grid pass of the detector: corner identities from the board's topology, not from one pixel.

The network's per-slot heatmaps must recognise *which* of the 54 corners a blob is from global
context alone, and that is what trains slowest on a CPU budget. Its dense maps (board mask,
class-agnostic corner score, column / row classification of every pixel) train much faster.
This pass turns them into identities the way a person would (docs/detector.md has the details):

1. candidates: X-junctions of the full-resolution image inside the network's board region,
   moved to the saddle of a fitted quadratic (which also gives the two edge directions) and kept
   if the window is point-symmetric; next to the image circle's rim or the image border, from
   the part of the window that is seen;
2. growth: from a seed, neighbours are predicted one square step along each grid axis (from the
   last two steps: perspective's cross-ratio and the fisheye's bend) and matched to a candidate, or, when
   the network missed it, to a saddle found at the predicted spot; checker colours must
   alternate; a verification pass drops corners off their lattice lines, and lattices grown with
   skipped corners; the result is a lattice coordinate (a, b) per corner;
3. identity: the lattice is placed on the board by one of the four in-plane rotations and an
   integer offset; every placement is scored by the network's column / row log-probabilities at
   the corners, the checker colour of every lattice cell (square (i, j) of corners is black when
   i + j is even) and the board's white margin where the lattice stops, and the best one wins if
   it beats the runner-up by a margin (a board that looks the same turned, like 7 x 5 squares, is
   identified up to that turn: corner 0 goes nearest the image's top left);
4. positions: the reported corners are fitted once more in a small window (at most 3 px
   half-size), close to the junction, where bent edges and the blooming of real prints pull least.

So one identity decision is made per board from all its corners, and a corner only gets an id if
it is connected to the board's lattice. Pure functions over numpy arrays; pixels follow
CONVENTIONS (centre of the top-left pixel at (0, 0)).
"""

from __future__ import annotations

import collections
import functools
from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial import cKDTree


@dataclass
class GridConfig:
    region_threshold: float = 0.3  # corner-score or board-mask probability of a 1/4 cell that puts it in the searched region
    min_corners: int = 6  # smallest lattice that is reported
    min_cells: int = 2  # complete lattice squares (four corners) a reported lattice needs
    match_radius: float = 0.45  # a neighbour must lie within this fraction of the grid step of its prediction
    agree_radius: float = 0.3  # predictions of one corner from different neighbours must agree within this fraction of a step
    min_step_px: float = 7.0  # no growth into squares smaller than this (saddles of tinier squares are unreliable)
    min_board_prob: float = 0.3  # mean board probability (network mask) at a lattice's corners
    min_saddle_contrast: float = 0.04  # |eigenvalue| of the fitted quadratic * half^2 (intensity units) a saddle needs
    min_saddle_ratio: float = 0.03  # smaller / larger |eigenvalue|: below this the fit is an edge, not an X
    min_symmetry: float = 0.65  # correlation of the window with itself turned 180 deg (X-junctions are point-symmetric)
    parity_weight: float = 2.0  # log-likelihood per lattice cell whose checker colour agrees with a placement
    min_margin: float = 25.0  # the best placement must beat the runner-up by this (nats) to be reported
    max_seeds: int = 12  # seeds tried (best corner scores first); the lattice with the surest identity wins
    logp_floor: float = -3.0  # network log-probabilities are clamped here (one corner cannot veto a board)
    offboard_penalty: float = 10.0  # per lattice corner a placement puts off the board (they are verified X-junctions)
    max_violated_edges: float = 2.5  # margin evidence (corners' worth) a placement may contradict before the lattice is rejected
    edge_weight: float = 8.0  # per lattice corner whose outward neighbour is the board's white margin
    max_skipped: float = 0.3  # share of lattice steps (cells) with an X-junction at the midpoint (centre) that drops a lattice
    min_rim_px: float = 3.0  # corners closer than this to the image circle's dark rim or the image border are not reported
    max_rim_edge_angle: float = 15.0  # deg: a corner fitted in a window cut by the rim must have its edges along the lattice lines
    final_max_half: int = 3  # px: largest fit window half-size for the reported positions (see refine_positions)


# --------------------------------------------------------------------------------------------
# Saddle points
# --------------------------------------------------------------------------------------------
@functools.lru_cache(maxsize=16)
def _basis(half: int) -> tuple[np.ndarray, np.ndarray]:
    """Monomials A (n^2, 6) of the quadratic a x^2 + b xy + c y^2 + d x + e y + f over a
    (2 half + 1)^2 window (row-major, centre at 0) and their Gaussian weights w (n^2,)."""
    g = np.arange(2 * half + 1) - half
    X, Y = np.meshgrid(g, g)
    x, y = X.ravel().astype(np.float64), Y.ravel().astype(np.float64)
    w = np.exp(-(x**2 + y**2) / (2 * (0.6 * half) ** 2))
    return np.stack([x * x, x * y, y * y, x, y, np.ones_like(x)], 1), w


@functools.lru_cache(maxsize=16)
def _design(half: int) -> np.ndarray:
    """Weighted least-squares solver of the window quadratic (see :func:`_basis`):
    coefficients = pinv @ patch.ravel()."""
    A, w = _basis(half)
    return np.linalg.pinv(A * w[:, None]) * w[None, :]


def _masked_coefficients(patch: np.ndarray, valid: np.ndarray, half: int) -> tuple[np.ndarray, np.ndarray]:
    """Quadratic coefficients (K, 6) fitted to the valid pixels of each window only (``valid``
    (K, n^2) in [0, 1]), and whether the fit is posed (K,): at least half the Gaussian weight valid."""
    A, w = _basis(half)
    wv = valid * w[None]  # (K, n^2)
    M = np.einsum("ki,ip,iq->kpq", wv, A, A)  # A^T W A per window (K, 6, 6)
    rhs = np.einsum("ki,ip,ki->kp", wv, A, patch)
    posed = wv.sum(1) >= 0.5 * w.sum()
    M[~posed] = np.eye(6)
    M += 1e-9 * np.eye(6)  # half a window of a quadratic is well posed; this only guards the solve
    return np.linalg.solve(M, rhs[..., None])[..., 0], posed


def _patches(img: np.ndarray, p: np.ndarray, half: int, border: int = cv2.BORDER_REPLICATE) -> np.ndarray:
    """Bilinear (2 half + 1)^2 windows of ``img`` centred on points p (K, 2) -> (K, n * n)."""
    n = 2 * half + 1
    g = np.arange(n, dtype=np.float32) - half
    mx = (p[:, 0, None, None] + g[None, None, :]).astype(np.float32) + np.zeros((1, n, 1), np.float32)
    my = (p[:, 1, None, None] + g[None, :, None]).astype(np.float32) + np.zeros((1, 1, n), np.float32)
    out = cv2.remap(img, mx.reshape(-1, n), my.reshape(-1, n), cv2.INTER_LINEAR, borderMode=border, borderValue=0)
    return out.reshape(len(p), n * n).astype(np.float64)


def saddle_fit(
    smoothed: np.ndarray,
    xy: np.ndarray,
    half: int,
    iterations: int = 4,
    cfg: GridConfig | None = None,
    rim_dist: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Move points to the saddle of a quadratic fitted in a (2 half + 1)^2 window (Newton steps,
    a fixed number of them, all points at once).

    Args:
        smoothed: (H, W) float32 grey image, already blurred for this window size.
        xy: (K, 2) start points, pixels.
        rim_dist: optional (H, W) float32 distance in pixels to the nearest unusable pixel (outside
            the image circle or the image). Window pixels the blur has mixed with unusable ones
            (closer than 1 + 0.8 half) are left out of the fit and of the symmetry test, so a corner
            next to the rim is fitted from the part of its X-junction that is seen; at least half
            the window's weight must remain and the saddle must lie ``cfg.min_rim_px`` from the rim.
            Without it, the window must lie inside the image.
    Returns:
        xy: (K, 2) saddle points (start point where the fit failed);
        ok: (K,) bool, a saddle with enough contrast and X shape, converged within half a window;
        axes: (K, 2, 2) unit edge directions (the quadratic's zero lines) per point.
    """
    cfg = cfg or GridConfig()
    pinv = _design(half)
    xy = np.asarray(xy, np.float64).reshape(-1, 2)
    K = len(xy)
    H, W = smoothed.shape
    reach = 1.0 + 0.8 * half

    def fit(q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Coefficients (k, 6), patches (k, n^2), valid weights (k, n^2), posed (k,) at points q."""
        patch = _patches(smoothed, q, half)
        if rim_dist is None:
            return patch @ pinv.T, patch, np.ones_like(patch), np.ones(len(q), bool)
        coef, valid, posed = patch @ pinv.T, np.ones_like(patch), np.ones(len(q), bool)
        qi = np.clip(np.rint(q).astype(int), 0, [W - 1, H - 1])
        near = rim_dist[qi[:, 1], qi[:, 0]] < reach + 1.5 * half + 1  # the window may reach the rim
        if near.any():
            valid[near] = (_patches(rim_dist, q[near], half, cv2.BORDER_CONSTANT) > reach).astype(np.float64)
            cut = near & (valid.min(1) < 1)  # only windows that reach the rim need the masked solve
            if cut.any():
                coef[cut], posed[cut] = _masked_coefficients(patch[cut], valid[cut], half)
        return coef, patch, valid, posed

    p = xy.copy()
    alive = np.ones(K, bool)
    for _ in range(iterations):
        idx = np.nonzero(alive)[0]
        if not len(idx):
            break
        coef, _, _, posed = fit(p[idx])
        a, b, c, d, e, _ = coef.T
        det = 4 * a * c - b * b  # of [[2a, b], [b, 2c]]; a saddle has det < 0
        safe = np.where(det < 0, det, -1.0)
        step = -np.stack([2 * c * d - b * e, -b * d + 2 * a * e], 1) / safe[:, None]
        bad = (det >= 0) | (np.linalg.norm(step, axis=1) > half) | ~posed
        p[idx[~bad]] += step[~bad]
        alive[idx[bad]] = False
    if rim_dist is None:
        inside = (p[:, 0] >= half) & (p[:, 0] < W - 1 - half) & (p[:, 1] >= half) & (p[:, 1] < H - 1 - half)
    else:
        pi = np.clip(np.rint(p).astype(int), 0, [W - 1, H - 1])
        inside = (p[:, 0] >= 0) & (p[:, 0] <= W - 1) & (p[:, 1] >= 0) & (p[:, 1] <= H - 1)
        inside &= rim_dist[pi[:, 1], pi[:, 0]] >= cfg.min_rim_px
    ok = alive & inside & (np.linalg.norm(p - xy, axis=1) <= half)
    axes = np.zeros((K, 2, 2))
    idx = np.nonzero(ok)[0]
    if len(idx):
        coef, patch, valid, posed = fit(p[idx])
        a, b, c = coef.T[:3]
        # Point symmetry over the pixel pairs seen on both sides (a 180 deg turn = reversed ravel).
        pair = valid * valid[:, ::-1]
        mean = (patch * valid).sum(1, keepdims=True) / np.maximum(valid.sum(1, keepdims=True), 1)
        z = patch - mean
        sym = (z * z[:, ::-1] * pair).sum(1) >= cfg.min_symmetry * np.maximum((z * z * pair).sum(1), 1e-12)
        sym &= pair.sum(1) >= 0.3 * pair.shape[1]
        lam, vec = np.linalg.eigh(np.stack([np.stack([a, b / 2], -1), np.stack([b / 2, c], -1)], -2))  # lam[:, 0] <= lam[:, 1]
        neg, pos = -lam[:, 0], lam[:, 1]
        big = np.maximum(np.maximum(neg, pos), 1e-12)
        good = posed & sym & (neg > 0) & (pos > 0) & (big * half * half >= cfg.min_saddle_contrast)
        good &= np.minimum(neg, pos) / big >= cfg.min_saddle_ratio
        t = np.arctan(np.sqrt(np.maximum(pos, 0) / np.maximum(neg, 1e-12)))  # zero lines: cos t e_pos +- sin t e_neg
        e_pos, e_neg = vec[:, :, 1], vec[:, :, 0]
        axes[idx, 0] = np.cos(t)[:, None] * e_pos + np.sin(t)[:, None] * e_neg
        axes[idx, 1] = np.cos(t)[:, None] * e_pos - np.sin(t)[:, None] * e_neg
        ok[idx] = good
    return np.where(ok[:, None], p, xy), ok, axes


def fit_saddles(
    grey: np.ndarray,
    smoothed: dict[int, np.ndarray],
    xy: np.ndarray,
    half: int,
    cfg: GridConfig,
    rim_dist: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`saddle_fit` on the image blurred for ``half`` (cached in ``smoothed``); where that
    fails within reach of the rim (``rim_dist``), again with smaller windows (half // 2, then 2),
    whose lighter blur reaches less far: a corner cut by the image circle keeps enough of its
    X-junction only in a small window."""
    q, ok, axes = saddle_fit(_cached(smoothed, grey, half), xy, half, cfg=cfg, rim_dist=rim_dist)
    if rim_dist is None:
        return q, ok, axes
    H, W = rim_dist.shape
    xi = np.clip(np.rint(xy).astype(int), 0, [W - 1, H - 1])
    near = rim_dist[xi[:, 1], xi[:, 0]] < 1 + 1.8 * half  # the window (and its blur) reaches the rim
    for h in sorted({max(2, half // 2), 2}, reverse=True):
        retry = np.nonzero(~ok & near)[0]
        if h >= half or not len(retry):
            continue
        q[retry], ok[retry], axes[retry] = saddle_fit(_cached(smoothed, grey, h), xy[retry], h, cfg=cfg, rim_dist=rim_dist)
    return q, ok, axes


def window_half(spacing_px: float | np.ndarray, max_half: int = 5) -> int | np.ndarray:
    """Fit window half-size for a local grid spacing (px): about a third of a square, 2 .. max_half.

    Larger windows are no better: on real prints the edges bend (the fisheye) and the white
    squares bloom into the black ones, so a wide fit leans off the junction (measured on the
    BoofCV frames: calibration RMS 0.41 px with windows up to 8, 0.26 up to 5)."""
    h = np.clip(np.rint(0.3 * np.asarray(spacing_px)), 2, max_half).astype(int)
    return int(h) if h.ndim == 0 else h


def smooth_for(grey: np.ndarray, half: int) -> np.ndarray:
    """The image blurred for a fit window of half-size ``half`` (sigma = half / 2.5, at least 0.7);
    ``half = -1``: sigma 1 px, for sampling colours."""
    return cv2.GaussianBlur(grey.astype(np.float32), (0, 0), 1.0 if half < 0 else max(0.7, half / 2.5))


def _cached(smoothed: dict[int, np.ndarray], grey: np.ndarray, half: int) -> np.ndarray:
    """:func:`smooth_for`, computed once per image and window size."""
    if half not in smoothed:
        smoothed[half] = smooth_for(grey, half)
    return smoothed[half]


# --------------------------------------------------------------------------------------------
# Candidates
# --------------------------------------------------------------------------------------------
def saddle_response(grey: np.ndarray, sigma: float = 1.5) -> np.ndarray:
    """(H, W) scale-normalised negative Hessian determinant -(Ixx Iyy - Ixy^2) sigma^4: large at
    X-junctions, near zero along edges."""
    g = cv2.GaussianBlur(grey.astype(np.float32), (0, 0), sigma)
    ixx = cv2.Sobel(g, cv2.CV_32F, 2, 0, ksize=3)
    iyy = cv2.Sobel(g, cv2.CV_32F, 0, 2, ksize=3)
    ixy = cv2.Sobel(g, cv2.CV_32F, 1, 1, ksize=3)
    return -(ixx * iyy - ixy * ixy) * sigma**4


def saddle_candidates(
    grey: np.ndarray, roi: np.ndarray, max_candidates: int = 600, min_response: float = 0.002, response: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """X-junction candidates: local maxima (5x5) of :func:`saddle_response` (or the given
    ``response``) inside ``roi`` (H, W bool). Returns xy (K, 2) pixels and response (K,), strongest first."""
    D = saddle_response(grey) if response is None else response
    peak = (D >= cv2.dilate(D, np.ones((5, 5), np.uint8))) & (D > min_response) & roi
    ys, xs = np.nonzero(peak)
    r = D[ys, xs]
    order = np.argsort(-r)[:max_candidates]
    return np.stack([xs[order], ys[order]], 1).astype(np.float64), r[order].astype(np.float64)


def outside_circle(grey: np.ndarray, dark: float = 0.04, grow_px: int = 1) -> np.ndarray:
    """(H, W) bool: the black frame outside a fisheye's image circle (dark regions connected to
    the image border, found at half resolution), grown by ``grow_px``. Corners there sit on the
    rim, where the checker is cut and a saddle fit is pulled off the corner."""
    H, W = grey.shape
    small = cv2.resize(grey, (max(1, W // 2), max(1, H // 2)), interpolation=cv2.INTER_AREA)
    low = (cv2.GaussianBlur(small, (0, 0), 0.7) < dark).astype(np.uint8)
    n, lab = cv2.connectedComponents(low, connectivity=4)
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    keep = np.zeros(n, np.uint8)
    keep[border[border > 0]] = 1
    out = cv2.resize(keep[lab], (W, H), interpolation=cv2.INTER_NEAREST)
    k = 2 * grow_px + 1
    return cv2.dilate(out, np.ones((k, k), np.uint8)) > 0


def roi_from_maps(prob: np.ndarray, shape: tuple[int, int], scale: float, threshold: float = 0.3) -> np.ndarray:
    """Full-resolution (H, W) bool region from a 1/4-processing-resolution probability map:
    cells above ``threshold``, grown by two cells, mapped back through the letterbox
    (input pixel x -> processing (x + 0.5) s - 0.5 -> cell (. - 1.5) / 4)."""
    m = cv2.dilate((prob > threshold).astype(np.uint8), np.ones((5, 5), np.uint8))
    H, W = shape
    k, t = scale / 4, (0.5 * scale - 2.0) / 4
    M = np.array([[k, 0, t], [0, k, t]], np.float64)
    full = cv2.warpAffine(m, M, (W, H), flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE)
    return full > 0


# --------------------------------------------------------------------------------------------
# Lattice growth
# --------------------------------------------------------------------------------------------
@dataclass
class Lattice:
    xy: np.ndarray  # (K, 2) corner pixels
    ab: np.ndarray  # (K, 2) integer lattice coordinates
    filled: np.ndarray  # (K,) True where the corner was found by a saddle search at its predicted spot, not among the candidates


def _cross(u: np.ndarray, v: np.ndarray) -> float:
    return float(u[0] * v[1] - u[1] * v[0])


def _value(img: np.ndarray, q: np.ndarray) -> float:
    """Bilinear value of ``img`` at one point (exact sub-pixel position, border replicated)."""
    return float(cv2.getRectSubPix(img, (1, 1), (float(q[0]), float(q[1])))[0, 0])


def _diag_contrast(img: np.ndarray, p: np.ndarray, ea: np.ndarray, eb: np.ndarray) -> float:
    """Brightness of the (+a, -b) / (-a, +b) quadrants minus the (+a, +b) / (-a, -b) ones around
    corner ``p`` (steps ``ea``, ``eb``): its sign alternates between lattice neighbours on a checker."""
    d1, d2 = 0.3 * (ea + eb), 0.3 * (ea - eb)
    return _value(img, p + d2) + _value(img, p - d2) - _value(img, p + d1) - _value(img, p - d1)


def next_step(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """The image step after steps ``u`` then ``v`` (2,) along one lattice line.

    Equal steps on the board seen in perspective keep their cross-ratio: with step lengths
    d0 = |u|, d1 = |v| the next one is d1 (d0 + d1) / (3 d0 - d1) (clamped to 0.5 .. 2 d1), and
    the fisheye bends the line by about the same angle again (clamped to 30 deg)."""
    d0, d1 = float(np.linalg.norm(u)), float(np.linalg.norm(v))
    den = 3 * d0 - d1
    ratio = float(np.clip((d0 + d1) / den, 0.5, 2.0)) if den > 0 else 2.0
    turn = float(np.clip(np.arctan2(_cross(u, v), float(np.dot(u, v))), -np.pi / 6, np.pi / 6))
    c, s = np.cos(turn), np.sin(turn)
    return ratio * np.array([c * v[0] - s * v[1], s * v[0] + c * v[1]])


def grow_lattice(
    xy: np.ndarray,
    axes: np.ndarray,
    seed: int,
    grey: np.ndarray,
    cfg: GridConfig,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray | None = None,
) -> Lattice | None:
    """Breadth-first lattice growth from candidate ``seed`` (see the module docstring); corners
    found by the saddle search are fitted with ``rim_dist`` (see :func:`saddle_fit`).

    Lattice axes are oriented so that a x b > 0 in the image (x right, y down), as the board's own
    i, j axes are when its printed side is seen.
    """
    tree = cKDTree(xy)
    p0 = xy[seed]
    d, nb = tree.query(p0, k=min(9, len(xy)))
    steps = []
    for u in axes[seed]:
        best = None
        for sgn in (1, -1):
            for dist, j in zip(d[1:], nb[1:]):
                if not np.isfinite(dist) or dist < 1.0:
                    continue
                v = xy[j] - p0
                if np.dot(v, sgn * u) / dist > np.cos(np.radians(20)) and (best is None or dist < best[0]):
                    best = (dist, sgn * v)
        if best is None:
            return None
        steps.append(best[1])
    sa, sb = steps
    if abs(_cross(sa, sb)) < 0.2 * np.linalg.norm(sa) * np.linalg.norm(sb):
        return None
    if _cross(sa, sb) < 0:
        sa, sb = sb, sa
    pts = [p0.copy()]
    sm1 = _cached(smoothed, grey, 2)
    par = {(0, 0): _diag_contrast(sm1, p0, sa, sb)}
    if abs(par[(0, 0)]) < 0.05:
        return None
    lab = [(0, 0)]
    filled = [False]
    step = {(0, 0): (sa, sb)}
    where = {(0, 0): 0}
    used = {seed}
    queue = collections.deque([(0, 0)])
    H, W = grey.shape
    while queue:
        a, b = queue.popleft()
        k = where[(a, b)]
        sa, sb = step[(a, b)]
        for da, db in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            t = (a + da, b + db)
            if t in where:
                continue
            back = where.get((a - da, b - db))
            v = pts[k] - pts[back] if back is not None else da * sa + db * sb
            back2 = where.get((a - 2 * da, b - 2 * db))
            if back is not None and back2 is not None:
                v = next_step(pts[back] - pts[back2], v)
            preds = [pts[k] + v]
            for side in ((db, da), (-db, -da)):  # the perpendicular neighbours' own steps along (da, db)
                m0, m1 = where.get((a + side[0], b + side[1])), where.get((t[0] + side[0], t[1] + side[1]))
                if m0 is not None and m1 is not None:
                    preds.append(pts[k] + pts[m1] - pts[m0])
            pred = np.mean(preds, 0)
            if max(np.linalg.norm(p_ - pred) for p_ in preds) > cfg.agree_radius * np.linalg.norm(v):
                continue  # the neighbours disagree about where this corner is
            short = min(np.linalg.norm(v), np.linalg.norm(sb if da else sa))  # the square's smaller side here
            r = cfg.match_radius * np.linalg.norm(v)
            if not (0 <= pred[0] < W and 0 <= pred[1] < H) or short < cfg.min_step_px:
                continue
            found, was_filled = None, False
            dist, j = tree.query(pred)
            if dist < r and j not in used:
                # A candidate is offered once: if the checks below refuse it here, it is doubtful
                # and is not tried again from another corner (measured: offering it again lets
                # wrong corners into small squares).
                found = xy[j]
                used.add(int(j))
            else:
                q, ok, _ = fit_saddles(grey, smoothed, pred[None], window_half(short), cfg, rim_dist)
                if ok[0] and np.linalg.norm(q[0] - pred) < r:
                    found, was_filled = q[0], True
            if found is None:
                continue
            new_v = found - pts[k]
            if np.linalg.norm(new_v) < 0.5 * np.linalg.norm(v) or np.linalg.norm(new_v) > 2.0 * np.linalg.norm(v):
                continue
            crowd = short if short >= 1.5 * cfg.min_step_px else np.linalg.norm(v)
            if min(np.linalg.norm(np.array(pts) - found, axis=1)) < 0.5 * crowd:
                # Would sit on top of a lattice corner already placed. Measured against the smaller
                # side (on a board seen obliquely the next corner across is much nearer than the
                # step), except in small squares, where a diagonal slip is then let through.
                continue
            na = new_v * da if da else sa
            nbv = new_v * db if db else sb
            pc = _diag_contrast(sm1, np.asarray(found), na, nbv)
            if pc * par[(a, b)] >= 0 or abs(pc) < 0.25 * abs(par[(a, b)]):
                continue  # checker colours do not alternate: a slipped row or column, or not this board
            par[t] = pc
            where[t] = len(pts)
            pts.append(np.asarray(found, np.float64))
            lab.append(t)
            filled.append(was_filled)
            step[t] = (na, nbv)
            queue.append(t)
    return Lattice(np.array(pts), np.array(lab, int), np.array(filled))


def _largest_component(ab: np.ndarray) -> np.ndarray:
    """(K,) bool: the largest 4-connected set of lattice coordinates."""
    where = {tuple(t): k for k, t in enumerate(ab.tolist())}
    comp = -np.ones(len(ab), int)
    n = 0
    for k0 in range(len(ab)):
        if comp[k0] >= 0:
            continue
        comp[k0] = n
        stack = [k0]
        while stack:
            a, b = ab[stack.pop()]
            for t in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)):
                m = where.get(t)
                if m is not None and comp[m] < 0:
                    comp[m] = n
                    stack.append(m)
        n += 1
    return comp == np.bincount(comp).argmax() if len(ab) else np.zeros(0, bool)


def verify_lattice(
    lat: Lattice, grey: np.ndarray, cfg: GridConfig, smoothed: dict[int, np.ndarray], rim_dist: np.ndarray | None = None
) -> Lattice:
    """Second look at every corner with its final neighbours. A corner is dropped when

    - the local square (smaller side) is under ``min_step_px``;
    - a saddle refit in a window sized for the square (with ``rim_dist``, see :func:`saddle_fit`:
      near the image circle's rim from the part of the window that is seen) does not land on it again,
      or, where the window is cut by the rim, its edge directions do not follow the lattice lines
      (within ``max_rim_edge_angle``);
    - it breaks a lattice line: the midpoint of its two neighbours along a, or along b, misses it
      by more than 0.4 of a step (where a group of corners slipped by a diagonal step during the
      growth, the corners along the seam fail this).
    Of what is left, the largest 4-connected part is kept.
    """
    where = {tuple(t): k for k, t in enumerate(lat.ab.tolist())}
    K = len(lat.ab)
    H, W = grey.shape
    short, oblique = np.zeros(K), np.zeros(K, bool)
    todo = np.zeros(K, bool)
    for (a, b), k in where.items():
        sides = []
        straight = True
        for nbrs in (((a + 1, b), (a - 1, b)), ((a, b + 1), (a, b - 1))):
            d = [np.linalg.norm(lat.xy[where[t]] - lat.xy[k]) for t in nbrs if t in where]
            if d:
                sides.append(min(d))
            if len(d) == 2:
                p1, p2 = lat.xy[where[nbrs[0]]], lat.xy[where[nbrs[1]]]
                straight &= bool(np.linalg.norm((p1 + p2) / 2 - lat.xy[k]) < 0.4 * np.linalg.norm(p1 - p2) / 2)
        if sides and min(sides) >= cfg.min_step_px and straight:
            todo[k] = True
            short[k] = min(sides)
            oblique[k] = len(sides) == 2 and max(sides) > 2 * min(sides)
    # Refit all corners at once, per window size.
    halves = np.where(todo, window_half(np.maximum(short, 1.0)), 0)
    q, ok, axes = lat.xy.copy(), np.zeros(K, bool), np.zeros((K, 2, 2))
    for h in np.unique(halves[todo]):
        m = todo & (halves == h)
        q[m], ok[m], axes[m] = fit_saddles(grey, smoothed, lat.xy[m], int(h), cfg, rim_dist)
    # Squares seen very obliquely (sides over 2:1) and blurred: at every other corner the two black
    # squares meet along the short diagonal and merge in a large window; a smaller one still sees
    # the X. (Not elsewhere: next to occluders it lets false junctions in.)
    retry = todo & ~ok & oblique & (halves > 2)
    first = halves.copy()
    for h in np.unique(first[retry]):
        m = retry & (first == h)
        halves[m] = max(2, int(h) // 2)
        q[m], ok[m], axes[m] = fit_saddles(grey, smoothed, lat.xy[m], max(2, int(h) // 2), cfg, rim_dist)
    keep = todo & ok & (np.linalg.norm(q - lat.xy, axis=1) < 0.15 * short)
    if rim_dist is not None:
        qi = np.clip(np.rint(q).astype(int), 0, [W - 1, H - 1])
        cut = keep & (rim_dist[qi[:, 1], qi[:, 0]] < 1 + 1.8 * halves)
        cos_max = np.cos(np.radians(cfg.max_rim_edge_angle))
        for k in np.nonzero(cut)[0]:
            # Cut by the rim, a square's corner against the margin or the rim can pass for half an
            # X-junction: the fitted edges must run along the lattice lines to the neighbours.
            a, b = lat.ab[k]
            for t in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)):
                if t in where:
                    u = lat.xy[where[t]] - q[k]
                    u = u / max(np.linalg.norm(u), 1e-9)
                    keep[k] &= bool(np.abs(axes[k] @ u).max() >= cos_max)
    xy = np.where(keep[:, None], q, lat.xy)
    lat = Lattice(xy[keep], lat.ab[keep], lat.filled[keep])
    big = _largest_component(lat.ab)
    return Lattice(lat.xy[big], lat.ab[big], lat.filled[big])


def refine_positions(
    lat: Lattice, grey: np.ndarray, cfg: GridConfig, smoothed: dict[int, np.ndarray], rim_dist: np.ndarray | None = None
) -> Lattice:
    """The reported positions: every corner fitted once more in a window of at most
    ``cfg.final_max_half`` (about a third of its square's smaller side below that). The search
    and the checks above need the larger windows' robustness; the position is best taken close to
    the junction, where the bent edges and the blooming of real prints pull it least (BoofCV
    frames: calibration RMS 0.26 -> 0.21 px). A corner whose fit fails or moves by over 0.15 of
    its square keeps its position."""
    where = {tuple(t): k for k, t in enumerate(lat.ab.tolist())}
    short = np.full(len(lat.ab), np.inf)
    for (a, b), k in where.items():
        for t in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)):
            if t in where:
                short[k] = min(short[k], float(np.linalg.norm(lat.xy[where[t]] - lat.xy[k])))
    short = np.where(np.isfinite(short), short, 3 * cfg.min_step_px)
    halves = window_half(short, cfg.final_max_half)
    xy = lat.xy.copy()
    for h in np.unique(halves):
        idx = np.nonzero(halves == h)[0]
        q, ok, _ = fit_saddles(grey, smoothed, lat.xy[idx], int(h), cfg, rim_dist)
        good = ok & (np.linalg.norm(q - lat.xy[idx], axis=1) < 0.15 * short[idx])
        xy[idx[good]] = q[good]
    return Lattice(xy, lat.ab, lat.filled)


def _sample(img: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Bilinear values of ``img`` at points (..., 2); NaN outside the image."""
    flat = pts.reshape(-1, 2).astype(np.float32)
    v = cv2.remap(img, flat[:, :1], flat[:, 1:], cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=np.nan)
    return v.reshape(pts.shape[:-1])


def skipped_corners(lat: Lattice, response: np.ndarray) -> float:
    """Share of lattice steps (along a, along b) or cells whose midpoint is itself an X-junction
    (:func:`saddle_response` there over half that of the weakest end), the worst of the three.

    On the board, a step's midpoint lies on an edge between two squares and a cell's centre inside
    a square, where the response is near zero. A lattice grown with double steps, or with knight's
    moves (two along, one across: the colours still alternate), has corners at the one or the
    other; in small blurred squares the colour test alone lets them through."""
    where = {tuple(t): k for k, t in enumerate(lat.ab.tolist())}
    groups = []
    for da, db in ((1, 0), (0, 1)):
        groups.append([(k, where[(a + da, b + db)]) for (a, b), k in where.items() if (a + da, b + db) in where])
    cells = [(k, *(where.get(t) for t in ((a + 1, b), (a, b + 1), (a + 1, b + 1)))) for (a, b), k in where.items()]
    groups.append([c for c in cells if None not in c])
    worst = 0.0
    for g in groups:
        if len(g) < 3:
            continue
        idx = np.array(g)
        ends = _sample(response, lat.xy[idx])  # (P, 2 or 4)
        mid = _sample(response, lat.xy[idx].mean(1))
        worst = max(worst, float(np.mean(mid > 0.5 * ends.min(1))))
    return worst


# --------------------------------------------------------------------------------------------
# Identity
# --------------------------------------------------------------------------------------------
ROTATIONS = [np.array([[1, 0], [0, 1]]), np.array([[0, -1], [1, 0]]), np.array([[-1, 0], [0, -1]]), np.array([[0, 1], [-1, 0]])]


@functools.lru_cache(maxsize=8)
def board_symmetries(nx: int, ny: int) -> tuple[np.ndarray, ...]:
    """Corner id permutations (nx ny,) under which a board of nx x ny inner corners looks the same:
    turns that map its squares onto squares of the same colour. None for the default 10 x 7
    squares; the half turn for boards whose square counts are both odd or both even (7 x 5, 8 x 6);
    also the quarter turns for square boards of an odd count. Such boards give each corner its id
    only up to these turns."""
    sx, sy = nx + 1, ny + 1
    sq = np.stack(np.meshgrid(np.arange(sx), np.arange(sy), indexing="ij"), -1).reshape(-1, 2)
    ij = np.stack(np.meshgrid(np.arange(nx), np.arange(ny), indexing="ij"), -1).reshape(-1, 2)
    out = []
    for R in ROTATIONS[1:]:
        t = sq @ R.T
        t -= t.min(0)
        if not np.array_equal(t.max(0), [sx - 1, sy - 1]) or not np.array_equal(t.sum(1) % 2, sq.sum(1) % 2):
            continue
        c = ij @ R.T  # inner corners turn the same way (about the board centre)
        c -= c.min(0)
        perm = np.empty(nx * ny, int)
        perm[ij[:, 1] * nx + ij[:, 0]] = c[:, 1] * nx + c[:, 0]
        out.append(perm)
    return tuple(out)


def canonical_ids(ids: np.ndarray, xy: np.ndarray, nx: int, ny: int) -> np.ndarray:
    """For a symmetric board (:func:`board_symmetries`), the one of the equivalent id assignments
    that puts corner 0 nearest the image's top left (smallest x + y, where an affine fit of the
    corners' positions to their board coordinates places it), as OpenCV orders them; ids (K,)
    with -1 off the board, xy (K, 2) pixels."""
    perms = board_symmetries(nx, ny)
    on = ids >= 0
    if not perms or on.sum() < 3:
        return ids

    def corner0(v: np.ndarray) -> float:
        A = np.stack([v % nx, v // nx, np.ones_like(v)], 1).astype(np.float64)
        coef = np.linalg.lstsq(A, xy[on], rcond=None)[0]  # (3, 2): pixel = i c0 + j c1 + c2
        return float(coef[2].sum())

    best, best_key = ids, corner0(ids[on])
    for perm in perms:
        alt = ids.copy()
        alt[on] = perm[ids[on]]
        key = corner0(alt[on])
        if key < best_key - 1e-6:
            best, best_key = alt, key
    return best


def cell_darkness(blur: np.ndarray, lat: Lattice) -> dict[tuple[int, int], float]:
    """Per lattice cell (a, b) with all four corners known: +1 darker than its neighbour cells,
    -1 lighter (0 when it has no neighbour cell). Cell (a, b) is spanned by (a, b) .. (a+1, b+1).
    ``blur``: the image blurred by 1 px."""
    where = {tuple(t): k for k, t in enumerate(lat.ab.tolist())}
    val = {}
    for (a, b), k in where.items():
        quad = [where.get(t) for t in ((a + 1, b), (a, b + 1), (a + 1, b + 1))]
        if None in quad:
            continue
        c = lat.xy[[k, *quad]].mean(0)
        val[(a, b)] = _value(blur, c)
    out = {}
    for (a, b), v in val.items():
        nbs = [val[t] for t in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)) if t in val]
        out[(a, b)] = float(np.sign(np.mean(nbs) - v)) if nbs else 0.0
    return out


EDGE_T = np.arange(0.3, 2.0, 0.05)  # outward profile positions, in lattice steps


def edge_evidence(blur: np.ndarray, lat: Lattice) -> list[tuple[int, int, int, float]]:
    """Where the lattice stops because the board does: (k, da, db, e) for boundary corner k whose
    neighbour (a + da, b + db) is missing, e in [0, 1] the evidence that the squares end one
    square further on and the white margin follows.

    Beyond the last corner row there is one more row of squares, then the margin. Two profiles run
    outwards from the corner, half a square to either side: they differ across the last squares
    (one black, one white), and where the squares end (0.7 .. 1.6 steps out: perspective and the
    fisheye change the step) both turn white. Where the board goes on (occlusion, image edge, rim)
    the profiles keep differing, or turn dark, and there is no evidence. The outward step comes
    from the corner behind and the sideways step from a neighbour across; where one of them is
    missing (a lattice one corner deep, a corner at a tip) it is the other turned by 90 degrees
    (lattice axes have a x b > 0 in the image).
    """
    where = {tuple(t): k for k, t in enumerate(lat.ab.tolist())}
    jobs = []  # (k, da, db, p, out_step, across)
    for (a, b), k in where.items():
        for da, db in ((1, 0), (-1, 0), (0, 1), (0, -1)):
            if (a + da, b + db) in where:
                continue
            side = [where.get((a + db, b + da)), where.get((a - db, b - da))]  # neighbours across the direction
            back = where.get((a - da, b - db))
            if all(m is None for m in side) and back is None:
                continue
            # Image steps outwards and sideways (along lattice direction (db, da)); one of them may
            # come from the other turned by 90 degrees (rot90: b = rot90(a) in the image).
            rot90 = lambda v: np.array([-v[1], v[0]])  # noqa: E731
            if back is not None:
                out_step = lat.xy[k] - lat.xy[back]
            if any(m is not None for m in side):
                m = next(m for m in side if m is not None)
                sgn = 1.0 if m == side[0] else -1.0
                across = sgn * (lat.xy[m] - lat.xy[k])
                if back is None:
                    out_step = -rot90(across) if da else rot90(across)
            else:
                across = rot90(out_step) if da else -rot90(out_step)
            jobs.append((k, da, db, lat.xy[k], out_step, across))
    if not jobs:
        return []
    p = np.array([j[3] for j in jobs])[:, None, None, :]
    o = np.array([j[4] for j in jobs])[:, None, None, :]
    c = np.array([j[5] for j in jobs])[:, None, None, :]
    g = np.array([0.5, -0.5])[None, None, :, None]
    prof = _sample(blur, p + EDGE_T[None, :, None, None] * o + g * c)  # (J, T, 2)
    out = []
    i_half = int(np.argmin(np.abs(EDGE_T - 0.5)))
    for n, (k, da, db, *_rest) in enumerate(jobs):
        A, B = prof[n, :, 0], prof[n, :, 1]
        seen = np.cumprod(~(np.isnan(A) | np.isnan(B))).astype(bool)  # the profiles up to the image's edge
        if not seen[i_half]:
            continue
        diff = (A - B) * np.sign(A[i_half] - B[i_half])
        contrast = diff[i_half]
        if contrast < 0.1:
            continue
        ended = np.nonzero(seen & (EDGE_T > 0.5) & (diff < 0.5 * contrast))[0]
        if not len(ended) or not 0.7 <= EDGE_T[ended[0]] <= 1.6:
            continue
        t_end = EDGE_T[ended[0]]
        band = (EDGE_T >= t_end + 0.1) & (EDGE_T <= t_end + 0.25)  # inside the margin
        white = max(A[i_half], B[i_half]) - 0.5 * contrast
        if not seen[band].all() or not band.any() or min(A[band].min(), B[band].min()) < white:
            continue
        out.append((k, da, db, float(np.clip(1 - np.abs(A[band] - B[band]).mean() / contrast, 0, 1))))
    return out


def assign_ids(
    ab: np.ndarray,
    logp_col: np.ndarray,
    logp_row: np.ndarray,
    dark: dict[tuple[int, int], float],
    nx: int,
    ny: int,
    cfg: GridConfig,
    edges: list[tuple[int, int, int, float]] | None = None,
) -> tuple[np.ndarray, float, float, float]:
    """Place the lattice on the board.

    Args:
        ab: (K, 2) lattice coordinates; logp_col: (K, nx + 2) / logp_row: (K, ny + 2) the network's
        log-probabilities of the corner column -1 .. nx / row -1 .. ny at each corner;
        dark: cell darkness (see :func:`cell_darkness`); edges: margin evidence (see :func:`edge_evidence`).
    Returns: ids (K,) (-1 where the placement puts a corner off the board), best score, margin
    over the best placement that gives any corner another id (turns of a symmetric board, see
    :func:`board_symmetries`, do not count), and the margin evidence the best
    placement contradicts (sum of e over corners whose missing outward neighbour it puts on the
    board: large when the lattice is a whole board of another size).
    """
    lc = np.maximum(logp_col, cfg.logp_floor)
    lr = np.maximum(logp_row, cfg.logp_floor)
    cells = np.array(list(dark.keys()), int).reshape(-1, 2)
    dsign = np.array(list(dark.values()))
    results = []  # (score, rot, oi, oj)
    for r, R in enumerate(ROTATIONS):
        ij0 = ab @ R.T  # (K, 2) before the offset
        # Column score for every offset oi: sum_k lc[k, i_k + 1], i_k = ij0[k, 0] + oi (off-board -> floor).
        ois = np.arange(-ij0[:, 0].max() - 1, nx - ij0[:, 0].min() + 1)
        ojs = np.arange(-ij0[:, 1].max() - 1, ny - ij0[:, 1].min() + 1)
        ii = ij0[:, 0][:, None] + ois[None]  # (K, n_oi)
        jj = ij0[:, 1][:, None] + ojs[None]
        sc = np.where((ii >= 0) & (ii < nx), np.take_along_axis(lc, np.clip(ii + 1, 0, nx + 1), 1), -cfg.offboard_penalty).sum(0)
        sr = np.where((jj >= 0) & (jj < ny), np.take_along_axis(lr, np.clip(jj + 1, 0, ny + 1), 1), -cfg.offboard_penalty).sum(0)
        # Parity: the cell's min corner after rotation decides its colour; black when i + j even.
        par = np.zeros(2)
        if len(cells):
            quad = np.stack([cells, cells + [1, 0], cells + [0, 1], cells + [1, 1]], 1) @ R.T  # (C, 4, 2)
            mn = quad.min(1).sum(1)  # i0 + j0 without offset
            for e in (0, 1):  # e = (oi + oj) mod 2
                black = ((mn + e) % 2) == 0
                par[e] = cfg.parity_weight * float((np.where(black, 1.0, -1.0) * dsign).sum())
        total = sc[:, None] + sr[None, :] + par[(ois[:, None] + ojs[None, :]) % 2]
        if edges:
            # Margin evidence: the missing outward neighbour must fall off the board.
            kk = np.array([e[0] for e in edges])
            t0 = (ab[kk] + np.array([[e[1], e[2]] for e in edges])) @ R.T  # (E, 2) before the offset
            ev = np.array([e[3] for e in edges])
            ti = t0[:, 0, None, None] + ois[None, :, None]
            tj = t0[:, 1, None, None] + ojs[None, None, :]
            off = (ti < 0) | (ti >= nx) | (tj < 0) | (tj >= ny)  # (E, n_oi, n_oj)
            total = total + cfg.edge_weight * (ev[:, None, None] * np.where(off, 1.0, -1.0)).sum(0)
        for a, oi in enumerate(ois):
            for b, oj in enumerate(ojs):
                results.append((float(total[a, b]), r, int(oi), int(oj)))
    results.sort(key=lambda t: -t[0])
    best = results[0]

    def ids_of(res: tuple[float, int, int, int]) -> np.ndarray:
        ij = ab @ ROTATIONS[res[1]].T + [res[2], res[3]]
        on = (ij[:, 0] >= 0) & (ij[:, 0] < nx) & (ij[:, 1] >= 0) & (ij[:, 1] < ny)
        return np.where(on, ij[:, 1] * nx + ij[:, 0], -1)

    ids = ids_of(best)
    # On a symmetric board the turned placements give the same view: they are not competitors.
    on = ids >= 0
    same = [ids] + [np.where(on, perm[np.where(on, ids, 0)], -1) for perm in board_symmetries(nx, ny)]
    runner = next((r for r in results[1:] if not any(np.array_equal(ids_of(r), v) for v in same)), None)
    margin = best[0] - runner[0] if runner is not None else np.inf
    violated = 0.0
    for k, da, db, e in edges or []:
        i, j = (ab[k] + [da, db]) @ ROTATIONS[best[1]].T + [best[2], best[3]]
        violated += e if (0 <= i < nx and 0 <= j < ny) else 0.0
    return ids, best[0], margin, violated


# --------------------------------------------------------------------------------------------
# The whole pass
# --------------------------------------------------------------------------------------------
@dataclass
class GridResult:
    ids: np.ndarray  # (K,) corner ids
    xy: np.ndarray  # (K, 2) input-image pixels (saddle points)
    confidence: np.ndarray  # (K,)
    margin: float  # identity margin of the placement (nats); nan when no lattice was found


def sample_cells(maps: np.ndarray, q_proc: np.ndarray) -> np.ndarray:
    """Values of (C, h, w) 1/4-resolution maps at processing pixels (K, 2) (nearest cell) -> (K, C)."""
    C, h, w = maps.shape
    c = np.rint((q_proc - 1.5) / 4).astype(int)
    cx, cy = np.clip(c[:, 0], 0, w - 1), np.clip(c[:, 1], 0, h - 1)
    return maps[:, cy, cx].T


def find_candidates(
    grey: np.ndarray,
    roi: np.ndarray,
    offset: np.ndarray,
    scale: float,
    corner_prob: np.ndarray,
    cfg: GridConfig,
    smoothed: dict[int, np.ndarray],
    rim_dist: np.ndarray | None = None,
    response: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Saddle points inside ``roi`` (the network's corner / board region), best seeds first.

    ``grey`` and ``roi`` are a crop of the input whose top-left pixel is input pixel ``offset``.
    Returns xy (K, 2) crop pixels and axes (K, 2, 2) (see :func:`saddle_fit`)."""
    xy0, resp = saddle_candidates(grey, roi, response=response)
    if len(xy0) < 2:
        return np.zeros((0, 2)), np.zeros((0, 2, 2))
    # Window per candidate from the spacing to its nearest other candidate.
    d, _ = cKDTree(xy0).query(xy0, k=2)
    halves = window_half(d[:, 1])
    xy = np.zeros_like(xy0)
    ok = np.zeros(len(xy0), bool)
    axes = np.zeros((len(xy0), 2, 2))
    for h in np.unique(halves):
        m = halves == h
        xy[m], ok[m], axes[m] = fit_saddles(grey, smoothed, xy0[m], int(h), cfg, rim_dist)
    # Seeds in order of saddle response times the network's corner score there.
    q0 = (xy + offset + 0.5) * scale - 0.5
    score = resp * (sample_cells(corner_prob[None], q0)[:, 0] + 0.05)
    keep = np.nonzero(ok)[0]
    keep = keep[np.argsort(-score[keep])]
    # Merge candidates that converged onto the same saddle: the better-scored one stays.
    drop = np.zeros(len(keep), bool)
    for i, j in sorted(cKDTree(xy[keep]).query_pairs(1.0)):
        if not drop[i]:
            drop[j] = True
    keep = keep[~drop]
    return xy[keep], axes[keep]


def corner_votes(lat: Lattice, logp: np.ndarray, offset: np.ndarray, scale: float) -> np.ndarray:
    """Log-probabilities (K, C) of a dense column / row map for every lattice corner: the mean over
    the corner and the four points a quarter square away along the diagonals (all of them are
    nearest to this corner, so all share its column and row)."""
    where = {tuple(t): k for k, t in enumerate(lat.ab.tolist())}
    acc = np.zeros((len(lat.ab), logp.shape[0]))
    for k, (a, b) in enumerate(lat.ab.tolist()):
        pts = [lat.xy[k]]
        for da, db in ((1, 1), (1, -1), (-1, 1), (-1, -1)):
            n1, n2 = where.get((a + da, b)), where.get((a, b + db))
            if n1 is not None and n2 is not None:
                pts.append(lat.xy[k] + 0.25 * (lat.xy[n1] - lat.xy[k]) + 0.25 * (lat.xy[n2] - lat.xy[k]))
        q = (np.array(pts) + offset + 0.5) * scale - 0.5
        acc[k] = sample_cells(logp, q).mean(0)
    return acc


def grid_pass(
    grey: np.ndarray,
    scale: float,
    corner_prob: np.ndarray,
    mask_prob: np.ndarray,
    logp_col: np.ndarray,
    logp_row: np.ndarray,
    nx: int,
    ny: int,
    cfg: GridConfig,
) -> GridResult:
    """Corners with ids from the network's dense outputs and the full-resolution image.

    Args:
        grey: (H, W) float32 input image in [0, 1]; scale: processing pixels per input pixel.
        corner_prob: (h, w) class-agnostic corner probability and mask_prob: (h, w) board
        probability at 1/4 processing resolution; logp_col: (nx + 2, h, w), logp_row: (ny + 2, h, w)
        column / row log-probabilities.
    """
    empty = GridResult(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), float("nan"))
    # Work on the crop around the network's corner / board region (all full-resolution filtering
    # scales with its area); crop pixels + offset = input pixels.
    roi = roi_from_maps(np.maximum(corner_prob, mask_prob), grey.shape, scale, cfg.region_threshold)
    allowed = ~outside_circle(grey)
    allowed[[0, -1], :] = False  # the image's own border is a rim too
    allowed[:, [0, -1]] = False
    roi &= allowed
    ys, xs = np.nonzero(roi.any(1))[0], np.nonzero(roi.any(0))[0]
    if not len(ys):
        return empty
    pad = 12
    y0, y1 = max(0, ys[0] - pad), min(grey.shape[0], ys[-1] + 1 + pad)
    x0, x1 = max(0, xs[0] - pad), min(grey.shape[1], xs[-1] + 1 + pad)
    grey, roi, allowed = grey[y0:y1, x0:x1], roi[y0:y1, x0:x1], allowed[y0:y1, x0:x1]
    offset = np.array([x0, y0], np.float64)
    rim_dist = cv2.distanceTransform(allowed.astype(np.uint8), cv2.DIST_L2, 3)
    smoothed: dict[int, np.ndarray] = {}
    response = saddle_response(grey)
    xy, axes = find_candidates(grey, roi, offset, scale, corner_prob, cfg, smoothed, rim_dist, response)
    if len(xy) < cfg.min_corners:
        return empty
    # Grow from several seeds (distractors can hold the strongest saddles); a lattice must lie on
    # what the network calls board, and the one whose identity is surest wins.
    best: tuple[float, Lattice, np.ndarray] | None = None
    covered = np.zeros(len(xy), bool)
    tried = 0
    for seed in range(len(xy)):
        if tried >= cfg.max_seeds:
            break
        if covered[seed]:
            continue
        tried += 1
        lat = grow_lattice(xy, axes, seed, grey, cfg, smoothed, rim_dist)
        if lat is None:
            continue
        covered |= cKDTree(lat.xy).query(xy)[0] < 1.0
        lat = verify_lattice(lat, grey, cfg, smoothed, rim_dist)
        if len(lat.ab) < cfg.min_corners or skipped_corners(lat, response) > cfg.max_skipped:
            continue
        q_lat = (lat.xy + offset + 0.5) * scale - 0.5
        if sample_cells(mask_prob[None], q_lat)[:, 0].mean() < cfg.min_board_prob:
            continue
        blur1 = _cached(smoothed, grey, -1)
        dark = cell_darkness(blur1, lat)
        if len(dark) < cfg.min_cells:
            continue  # a line of corners (or a diagonal) is not a checker lattice
        lc, lr = corner_votes(lat, logp_col, offset, scale), corner_votes(lat, logp_row, offset, scale)
        edges = edge_evidence(blur1, lat)
        ids, _, margin, violated = assign_ids(lat.ab, lc, lr, dark, nx, ny, cfg, edges)
        if violated > max(cfg.max_violated_edges, 0.35 * sum(e[3] for e in edges)):
            continue  # the board ends where the target goes on: another target, or a distractor
        if best is None or margin > best[0]:
            best = (margin, lat, ids)
    if best is None:
        return empty
    margin, lat, ids = best
    if margin < cfg.min_margin:
        return GridResult(np.zeros(0, int), np.zeros((0, 2)), np.zeros(0), float(margin))
    lat = refine_positions(lat, grey, cfg, smoothed, rim_dist)
    ids = canonical_ids(ids, lat.xy, nx, ny)
    on = ids >= 0
    conf = np.full(len(ids), 1.0 - np.exp(-margin)) * np.where(lat.filled, 0.9, 1.0)
    order = np.argsort(ids[on])
    return GridResult(ids[on][order], lat.xy[on][order] + offset, conf[on][order], float(margin))
