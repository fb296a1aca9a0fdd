"""Tag pass, stage 4: reading the tags (:mod:`cotrain.detect.tag_pass`, step 4).

Takes a lattice (:class:`cotrain.detect.lattice.Lattice`) and the image; gives its tag cells read
(:class:`TagCell`, :func:`read_cells`): each tag with its four corners read through its own map
from its unit square to the image (:class:`TagMap`, :func:`tag_maps`: a homography, through the
lens guessed from the image circle where there is one, bent by the lattice corners around the
tag and by its sides as the image shows them, :func:`sides_seen`), its cells sharpened and split
by Otsu's threshold (:class:`TagLook`, :func:`look_at_tags`), and its nearest tag36h11 code over
the four turns (:data:`TURNS`, :func:`decode_many`). The seeds read their one tag with the same
functions (:func:`look_at_tag`, :func:`decode_bits`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import cv2
import numpy as np

from cotrain.detect.image_circle import EquidistantLens, ray_homographies
from cotrain.detect.lattice import Lattice
from cotrain.detect.sampling import values_at
from cotrain.detect.tag_config import TagConfig
from cotrain.targets.aprilgrid import BORDER_BITS, CELLS, DATA_BITS, N_CODES, printed_bits


def shortest_side(corners: np.ndarray) -> float:
    """The shortest side (px) of the quad ``corners`` (4, 2)."""
    return float(np.linalg.norm(corners - np.roll(corners, 1, 0), axis=1).min())


# Lattice-to-board turns: board corner-grid (c, r) = M (a, b) + offset. The lattice is oriented
# a x b > 0 in the image (y down) and Kalibr's page has y up, so M is a reflection (det -1).
# origin: code/table, not a threshold (the four reflections that map the lattice's axes onto the board's).
TURNS = (
    np.array([[1, 0], [0, -1]]),
    np.array([[-1, 0], [0, 1]]),
    np.array([[0, 1], [1, 0]]),
    np.array([[0, -1], [-1, 0]]),
)


@functools.lru_cache(maxsize=1)
def _codes() -> np.ndarray:
    """(N_CODES, 36) float: every tag36h11 code as printed, +1 white / -1 black, page cell (i, j)
    at j * 6 + i."""
    return printed_bits(N_CODES).reshape(N_CODES, -1).astype(np.float64) * 2 - 1


@functools.lru_cache(maxsize=1)
def _turn_index() -> np.ndarray:
    """(4, 36): for each of :data:`TURNS`, the page data cell of lattice data cell (p, q) (p along a,
    q along b; flat q * 6 + p)."""
    p, q = np.meshgrid(np.arange(DATA_BITS), np.arange(DATA_BITS))
    d = np.stack([p.ravel(), q.ravel()], 0) - (DATA_BITS - 1) / 2
    out = []
    for M in TURNS:
        i, j = np.rint(M @ d + (DATA_BITS - 1) / 2).astype(int)
        out.append(j * DATA_BITS + i)
    return np.array(out)


def page_order(soft: np.ndarray, turn: int) -> np.ndarray:
    """Data cells (..., 36) in lattice order -> page order under turn ``turn`` of :data:`TURNS`."""
    out = np.empty_like(soft)
    out[..., _turn_index()[turn]] = soft
    return out


@functools.lru_cache(maxsize=4)
def _unit_points(spacing: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Sample points of a tag in its unit square (u along a, v along b; corners at 0 and 1):
    3 x 3 points over the middle half of each data cell (36 * 9, 2; cell by cell in (p, q)
    order), border cell centres (64, 2), and points in the white gaps around the tag (12, 2), half
    a gap out."""
    c = (np.arange(CELLS) + 0.5) / CELLS
    U, V = np.meshgrid(c, c)
    idx = np.arange(CELLS)
    inner = (idx >= BORDER_BITS) & (idx < CELLS - BORDER_BITS)
    data = np.stack([U[np.ix_(inner, inner)].ravel(), V[np.ix_(inner, inner)].ravel()], 1)
    sub = np.stack(np.meshgrid([-0.25, 0, 0.25], [-0.25, 0, 0.25]), -1).reshape(-1, 2) / CELLS
    data = (data[:, None] + sub[None]).reshape(-1, 2)
    border = _border_mask()
    bord = np.stack([U[border], V[border]], 1)
    out = -spacing / 2
    s = np.array([0.3, 0.5, 0.7])
    gaps = np.concatenate(
        [
            np.stack([s, np.full(3, out)], 1),
            np.stack([s, np.full(3, 1 - out)], 1),
            np.stack([np.full(3, out), s], 1),
            np.stack([np.full(3, 1 - out), s], 1),
        ]
    )
    return data, bord, gaps


@dataclass
class TagLook:
    soft: np.ndarray  # (36,) data cells in lattice order (p + 6 q), sharpened, zero mean and unit RMS
    threshold: float  # the split of ``soft`` into black and white cells (two-class Otsu)
    contrast: float  # white gaps minus black border, intensity
    data_contrast: float  # mean white minus mean black data cell (split at ``threshold``), in units of ``contrast``
    clean: float  # share of the border's inner-ring samples darker, and gap samples lighter, than their midpoint

    @property
    def white(self) -> np.ndarray:
        """(36,) bool: the data cells read white."""
        return self.soft > self.threshold


def _quadratic(u: np.ndarray) -> np.ndarray:
    """(..., 2) -> (..., 6) monomials 1, u, v, uv, u^2, v^2."""
    x, y = u[..., 0], u[..., 1]
    return np.stack([np.ones_like(x), x, y, x * y, x * x, y * y], -1)


def _project(H: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Homographies H (T, 3, 3) applied to points p (T, n, 2) -> (T, n, 2), as
    ``cv2.perspectiveTransform`` does (a point at infinity goes to 0)."""
    x, y = p[..., 0], p[..., 1]
    h = H[:, None]
    w = h[..., 2, 0] * x + h[..., 2, 1] * y + h[..., 2, 2]
    inv = np.where(np.abs(w) > np.finfo(np.float64).eps, 1.0 / np.where(w == 0, 1.0, w), 0.0)
    px = (h[..., 0, 0] * x + h[..., 0, 1] * y + h[..., 0, 2]) * inv
    py = (h[..., 1, 0] * x + h[..., 1, 1] * y + h[..., 1, 2]) * inv
    return np.stack([px, py], -1)


@dataclass
class TagMap:
    """T tags' unit squares (u along a, v along b; corners at 0 and 1) -> image pixels (:func:`tag_maps`)."""

    H: np.ndarray  # (T, 3, 3) the homographies of the tags' four corners (to pixels; with a lens, to rays)
    coef: np.ndarray  # (T, 6, 2) the quadratics that bend the unit squares first (:func:`_quadratic`); zero: not bent
    misfit: np.ndarray  # (T,) the largest distance (tag widths) of a point found on a side from the fitted side; 0 without side points
    lens: EquidistantLens | None = None  # the lens guessed from the image circle; None: H maps to pixels

    def __call__(self, u: np.ndarray) -> np.ndarray:
        """(k, 2) unit coordinates (the same for every tag) or (T, k, 2) -> (T, k, 2) pixels."""
        u = np.broadcast_to(np.asarray(u, np.float64), (len(self.H), *np.shape(u)[-2:]))
        return _to_image(self.H, u + _quadratic(u) @ self.coef, self.lens)

    def take(self, idx: np.ndarray) -> TagMap:
        """The maps of tags ``idx`` (an index or bool mask over T)."""
        return TagMap(self.H[idx], self.coef[idx], self.misfit[idx], self.lens)


def _to_image(H: np.ndarray, u: np.ndarray, lens: EquidistantLens | None) -> np.ndarray:
    """Unit points u (T, n, 2) through homographies H (T, 3, 3) to pixels (T, n, 2): directly, or
    as rays through ``lens``."""
    if lens is None:
        return _project(H, u)
    x, y = u[..., 0], u[..., 1]
    h = H[:, None]
    return lens.project_xyz(*(h[..., i, 0] * x + h[..., i, 1] * y + h[..., i, 2] for i in range(3)))


def _to_unit(Hi: np.ndarray, p: np.ndarray, lens: EquidistantLens | None) -> np.ndarray:
    """Pixels p (T, n, 2) through the inverse homographies Hi (T, 3, 3) to unit points (T, n, 2):
    directly, or lifted to rays by ``lens`` first (a point at infinity goes to 0)."""
    if lens is None:
        return _project(Hi, p)
    v = lens.lift(p)
    w = (Hi[:, None] @ v[..., None])[..., 0]
    z = w[..., 2:]
    return np.where(np.abs(z) > np.finfo(np.float64).eps, w[..., :2] / np.where(z == 0, 1.0, z), 0.0)


def _corner_homographies(
    corners: np.ndarray, unit: np.ndarray, lens: EquidistantLens | None, homographies: np.ndarray | None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """:func:`tag_maps`' homographies from the unit square's corners ``unit`` (4, 2) float32 to T
    tags' corners (T, 4, 2) (with ``lens``, to their rays; ``homographies`` (T, 3, 3): given
    already): H (T, 3, 3), their inverses (zero where a tag has none) and where a tag has one (T,)
    bool (not where its corners give none, or a degenerate quad)."""
    T = len(corners)
    if homographies is not None:
        H, good = np.array(homographies, np.float64), np.ones(T, bool)  # NaN where the corners gave none
    elif lens is None:
        H = np.stack([cv2.getPerspectiveTransform(unit, c.astype(np.float32)) for c in corners]) if T else np.zeros((0, 3, 3))
        good = np.ones(T, bool)
    else:
        H, good = ray_homographies(lens.lift(corners))
        H[~good] = np.nan  # four rays no square of a plane gives: the tag's samples are NaN, it is not read
    finite = np.isfinite(H).all((1, 2))
    det = np.linalg.det(np.where(finite[:, None, None], H, np.eye(3)))
    good &= finite & (np.abs(det) >= 1e-12)  # elsewhere a degenerate quad: nothing to bend
    Hi = np.zeros_like(H)
    Hi[good] = np.linalg.inv(H[good])
    return H, Hi, good


def tag_maps(
    corners: np.ndarray,
    unit_more: list[np.ndarray] | None = None,
    more: list[np.ndarray] | None = None,
    side_px: np.ndarray | None = None,
    side_of: np.ndarray | None = None,
    side_ok: np.ndarray | None = None,
    lens: EquidistantLens | None = None,
    homographies: np.ndarray | None = None,
) -> TagMap:
    """The maps from T tags' unit squares to the image: the homography of each tag's four corners
    (``corners`` (T, 4, 2); with ``lens``, of their rays, so that the lens bends the square as it
    bends the tag), bent by a quadratic where more is known of how the fisheye bends the
    tag: lattice corners around it (``more[t]`` (n_t, 2) pixels at unit coordinates
    ``unit_more[t]`` (n_t, 2)), and points found on its sides (``side_px`` (T, m, 2) pixels on the
    sides ``side_of`` (T, m) of :data:`SIDES`, where ``side_ok`` (T, m) says they were found; see
    :func:`sides_seen`; such a point fixes only the coordinate across its side). Each coordinate's
    quadratic is fitted where it has at least 6 constraints besides the corners, by weighted least
    squares (the corners stay where they are, weight 10) with a little ridge: on two opposite
    sides alone, u and u^2 (or v and v^2) are one column. ``homographies`` (T, 3, 3): the corners'
    homographies where a map of these corners has them already (:attr:`TagMap.H`)."""
    corners = np.asarray(corners, np.float64)
    T = len(corners)
    unit = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    H, Hi, good = _corner_homographies(corners, unit, lens, homographies)
    n_more = [0 if more is None or more[t] is None else len(more[t]) for t in range(T)]
    m = 0 if side_px is None else side_px.shape[1]
    rows = 4 + max(n_more, default=0) + m
    U = np.zeros((2, T, rows, 2))  # per coordinate k: unit points, offsets, weights
    R = np.zeros((2, T, rows))
    Wt = np.zeros((2, T, rows))
    U[:, :, :4] = unit
    Wt[:, :, :4] = 10.0
    if rows > 4 + m:
        nm = rows - 4 - m
        um, pm = np.zeros((T, nm, 2)), np.zeros((T, nm, 2))
        for t, n in enumerate(n_more):
            if n:
                um[t, :n], pm[t, :n] = unit_more[t], more[t]
        there = np.arange(nm)[None] < np.array(n_more)[:, None]  # (T, nm)
        seen = _to_unit(Hi, pm, lens)
        U[:, :, 4 : 4 + nm] = um
        R[:, :, 4 : 4 + nm] = np.where(there, (seen - um).transpose(2, 0, 1), 0.0)
        Wt[:, :, 4 : 4 + nm] = there
    if m:
        seen = _to_unit(Hi, side_px, lens)
        ok = np.ones(side_px.shape[:2], bool) if side_ok is None else side_ok
        s0 = 4 + max(n_more, default=0)
        for k in range(2):
            on = (SIDES[side_of, 0] == k) & ok  # the sides on which coordinate k is fixed
            u = seen.copy()
            u[..., k] = SIDES[side_of, 1]
            U[k, :, s0:] = np.where(on[..., None], u, 0.0)  # rows not used: zero (a point not found may be NaN)
            R[k, :, s0:] = np.where(on, seen[..., k] - u[..., k], 0.0)
            Wt[k, :, s0:] = on
    A = _quadratic(U)  # (2, T, rows, 6)
    Aw = A * Wt[..., None]
    M = Aw.swapaxes(-1, -2) @ Aw + 1e-6 * np.eye(6)
    coef = np.linalg.solve(M, (Aw.swapaxes(-1, -2) @ (R * Wt)[..., None]))[..., 0]  # (2, T, 6)
    fit = ((Wt[:, :, 4:] > 0).sum(-1) >= 6) & good  # (2, T)
    coef = np.where(fit[..., None], coef, 0.0)
    misfit = np.zeros(T)
    if m:
        res = np.abs((A[:, :, s0:] @ coef[..., None])[..., 0] - R[:, :, s0:])  # (2, T, m)
        res = np.where((Wt[:, :, s0:] > 0) & fit[..., None], res, 0.0)
        misfit = res.max(axis=(0, 2))
    return TagMap(H, coef.transpose(1, 2, 0), misfit, lens)


def tag_map(
    corners: np.ndarray,
    unit_more: np.ndarray | None = None,
    more: np.ndarray | None = None,
    side_px: np.ndarray | None = None,
    side_of: np.ndarray | None = None,
) -> TagMap:
    """:func:`tag_maps` of one tag (``corners`` (4, 2); ``side_px`` (m, 2) on sides ``side_of`` (m,))."""
    sides = {} if side_px is None or not len(side_px) else {"side_px": np.asarray(side_px)[None], "side_of": np.asarray(side_of)[None]}
    return tag_maps(np.asarray(corners)[None], None if more is None else [unit_more], None if more is None else [more], **sides)


# A tag's sides in its unit square: (the coordinate fixed on it, its value), in the order
# v = 0 (a), u = 1, v = 1, u = 0; the unit normal into the tag follows. origin: code/table, not a threshold (the unit square's sides).
SIDES = np.array([[1, 0.0], [0, 1.0], [1, 1.0], [0, 0.0]])
_SIDE_INWARD = np.array([[0.0, 1.0], [-1.0, 0.0], [0.0, -1.0], [1.0, 0.0]])


@functools.lru_cache(maxsize=4)
def _side_samples(spacing: float, n: int) -> np.ndarray:
    """(4, n, 15, 2) unit-square samples of :func:`sides_seen`: on each side of :data:`SIDES`, at
    ``n`` points between its corners, from the gap's middle outside to 1.8 border cells in."""
    t = (np.arange(n) + 1) / (n + 1)
    s = np.linspace(-spacing / 2, 1.8 / CELLS, 15)
    base = np.empty((4, n, 2))
    for k, (fixed, value) in enumerate(SIDES):
        base[k, :, int(fixed)] = value
        base[k, :, 1 - int(fixed)] = t
    return base[:, :, None, :] + s[None, None, :, None] * _SIDE_INWARD[:, None, None, :]


def sides_seen(
    img: np.ndarray, to_image: TagMap, spacing: float, dark: np.ndarray, light: np.ndarray, n: int = 5
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Where T tags' sides are: on each side, at ``n`` points between its corners, the crossing of
    ``(dark + light) / 2`` ((T,) each) from the white gap into the black border, searched along the
    side's normal from the gap's middle to 1.8 border cells in (``to_image``: the tags' current
    maps, :func:`tag_maps`). Returns pixels (T, 4 n, 2), their sides (4 n,) (of :data:`SIDES`) and
    whether each was found (T, 4 n): sides cut by an occluder or blur give fewer points."""
    unit = _side_samples(float(spacing), n)  # (4, n, S, 2)
    S = unit.shape[2]
    T = len(to_image.H)
    px = to_image(unit.reshape(-1, 2)).reshape(T, 4 * n, S, 2)
    vals = values_at(img, px)
    mid = ((np.asarray(dark, np.float64) + np.asarray(light, np.float64)) / 2).astype(vals.dtype)[:, None, None]
    below = vals < mid
    # One crossing only, white gap outside, black border inside (sides cut by an occluder or blur fail).
    ok = np.isfinite(vals).all(-1) & ~below[..., 0] & below[..., -3:].all(-1) & ((below[..., 1:] != below[..., :-1]).sum(-1) == 1)
    j = np.maximum(below.argmax(-1), 1)[..., None]  # the first sample below the midpoint
    v0, v1 = np.take_along_axis(vals, j - 1, -1)[..., 0], np.take_along_axis(vals, j, -1)[..., 0]
    f = ((v0 - mid[..., 0]) / np.maximum(v0 - v1, vals.dtype.type(1e-9)))[..., None]
    p0, p1 = np.take_along_axis(px, j[..., None] - 1, -2)[..., 0, :], np.take_along_axis(px, j[..., None], -2)[..., 0, :]
    return p0 + f * (p1 - p0), np.arange(4 * n) // n, ok


def side_points(img: np.ndarray, to_image: TagMap, spacing: float, dark: float, light: float, n: int = 5) -> tuple[np.ndarray, np.ndarray]:
    """:func:`sides_seen` of one tag: the points found (m, 2) and their sides (m,)."""
    px, side, ok = sides_seen(img, to_image, spacing, np.array([dark]), np.array([light]), n)
    return px[0][ok[0]], side[ok[0]]


def look_at_tags(
    img: np.ndarray,
    corners: np.ndarray,
    spacing: float,
    unit_more: list[np.ndarray] | None = None,
    more: list[np.ndarray] | None = None,
    *,
    sharpen: float,
    max_side_misfit: float | None = None,
    lens: EquidistantLens | None = None,
) -> list[TagLook | None]:
    """Read the T tags whose corners, lattice (0, 0), (1, 0), (1, 1), (0, 1), are ``corners``
    (T, 4, 2) from ``img`` (H, W; unblurred: cells of small tags are 1-2 px) through each tag's own
    geometry (:func:`tag_maps`, with the lattice corners around it where given; never one
    homography per board: the fisheye bends the board); with ``max_side_misfit``, a tag's map is
    bent further to its sides found in the image (:func:`sides_seen`) where they fit it within
    that many tag widths (else a corner slid and the sides would hide it); None for a tag whose
    samples fall outside the image. The 10 x 10 cells are sharpened (a 4-neighbour Laplacian of
    weight ``sharpen``: blur darkens a white cell among black ones), the data cells standardised
    and split by Otsu's threshold, so a grey print, a dim corner or a blurred small tag reads as
    well as a clean one. All tags are read at once (the arithmetic is batched)."""
    corners = np.asarray(corners, np.float64)
    T = len(corners)
    if T == 0:
        return []
    data, bord, gaps = _unit_points(float(spacing))
    u = np.concatenate([data, bord, gaps])
    n = len(data)
    to_image = tag_maps(corners, unit_more, more, lens=lens)
    vals = values_at(img, to_image(u))  # (T, 400)
    seen = np.isfinite(vals).all(1)
    if max_side_misfit is not None:
        _bend_to_sides(img, corners, spacing, unit_more, more, lens, to_image, u, n, vals, seen, max_side_misfit)
    out: list[TagLook | None] = [None] * T
    ok = np.nonzero(seen)[0]
    if not len(ok):
        return out
    for t, look in zip(ok.tolist(), _looks(vals[ok], n, sharpen)):
        out[t] = look
    return out


def _bend_to_sides(
    img: np.ndarray,
    corners: np.ndarray,
    spacing: float,
    unit_more: list[np.ndarray] | None,
    more: list[np.ndarray] | None,
    lens: EquidistantLens | None,
    to_image: TagMap,
    u: np.ndarray,
    n: int,
    vals: np.ndarray,
    seen: np.ndarray,
    max_side_misfit: float,
) -> None:
    """:func:`look_at_tags`' second read: the T tags (``corners`` (T, 4, 2), read through maps
    ``to_image`` at unit points ``u`` (400, 2), the first ``n`` data samples, as ``vals`` (T, 400),
    ``seen`` (T,) where all lie in the image) read again, in place, through maps bent further to
    their sides as the image shows them, where those fit within ``max_side_misfit``."""
    bl, wh = _row_medians(vals[:, n : n + 64]), _row_medians(vals[:, n + 64 :])
    try_ = seen & (wh - bl > 0)
    if not try_.any():
        return
    # The sides as the image shows them bend the map further (a fisheye bends a tag's sides).
    idx = np.nonzero(try_)[0]
    sub = to_image.take(idx)
    side_px, side_of, side_ok = sides_seen(img, sub, spacing, bl[idx], wh[idx])
    bent = tag_maps(
        corners[idx],
        None if unit_more is None else [unit_more[t] for t in idx],
        None if more is None else [more[t] for t in idx],
        side_px,
        np.broadcast_to(side_of, side_ok.shape),
        side_ok,
        lens,
        sub.H,
    )
    use = bent.misfit <= max_side_misfit  # else the corners and the sides disagree: a corner slid
    if use.any():
        again = values_at(img, bent.take(use)(u))
        vals[idx[use]] = again
        seen[idx[use]] = np.isfinite(again).all(1)


def _looks(v: np.ndarray, n: int, sharpen: float) -> list[TagLook]:
    """:func:`look_at_tags`' reading of the samples v (R, 400) of R tags (the first ``n`` of each
    row their data samples, then 64 border and 12 gap samples): their looks, in order."""
    # v: the samples' own type (float32): means, medians and the level compared in it
    d, bv, gv = v[:, :n].reshape(len(v), 36, -1).mean(-1), v[:, n : n + 64], v[:, n + 64 :]
    bl, wh = _row_medians(bv).astype(np.float64), _row_medians(gv).astype(np.float64)
    mid = ((bl + wh) / 2).astype(v.dtype)[:, None]
    # Clean: the inner ring of the border (a cell and a half in from the sides) and the gaps; the
    # outer ring lies within half a cell of the sides, which the fisheye bends at the rim.
    clean = np.concatenate([bv[:, _inner_ring()] < mid, gv > mid], 1).mean(1)
    # Undo some of the blur: a white data cell among black ones reads darker than one among white
    # ones (cells of small tags are 1-2 px). Sharpen the 10 x 10 cells (border cells from their
    # centres) with a 4-neighbour Laplacian.
    grid = np.empty((len(v), CELLS, CELLS))
    inner = slice(BORDER_BITS, CELLS - BORDER_BITS)
    grid[:, _border_mask()] = bv
    grid[:, inner, inner] = d.reshape(-1, DATA_BITS, DATA_BITS)  # [q, p]
    lap = grid[:, :-2, 1:-1] + grid[:, 2:, 1:-1] + grid[:, 1:-1, :-2] + grid[:, 1:-1, 2:] - 4 * grid[:, 1:-1, 1:-1]
    sharp = (grid[:, 1:-1, 1:-1] - sharpen * lap / 4)[:, 1:-1, 1:-1].reshape(len(v), -1)
    centred = sharp - sharp.mean(1, keepdims=True)
    rms = np.maximum(np.sqrt((centred**2).mean(1, keepdims=True)), 1e-9)
    soft = centred / rms
    thr = otsu_splits(soft)
    white = soft > thr[:, None]
    n_white = white.sum(1)
    mean_w = (sharp * white).sum(1) / np.maximum(n_white, 1)
    mean_b = (sharp * ~white).sum(1) / np.maximum(36 - n_white, 1)
    spread = np.where((n_white > 0) & (n_white < 36), mean_w - mean_b, 0.0)
    looks = []
    for r in range(len(v)):
        c = float(wh[r] - bl[r])
        looks.append(TagLook(soft[r], float(thr[r]), c, float(spread[r]) / max(c, 1e-6), float(clean[r])))
    return looks


def _row_medians(x: np.ndarray) -> np.ndarray:
    """The median of each row of x (T, n), in x's type, as ``np.median(x, 1)`` gives it for rows
    without NaN (the mean of the two middle values where n is even) at a fraction of its cost: it
    runs for every tag looked at, often one at a time. A row with NaN gets a number, not NaN."""
    s = np.sort(x, 1)
    n = s.shape[1]
    return s[:, n // 2] if n % 2 else (s[:, n // 2 - 1] + s[:, n // 2]) / x.dtype.type(2)


def look_at_tag(
    img: np.ndarray,
    corners: np.ndarray,
    spacing: float,
    unit_more: np.ndarray | None = None,
    more: np.ndarray | None = None,
    *,
    sharpen: float,
    max_side_misfit: float | None = None,
    lens: EquidistantLens | None = None,
) -> TagLook | None:
    """:func:`look_at_tags` of one tag (``corners`` (4, 2), ``unit_more`` and ``more`` (n, 2))."""
    ring = {} if more is None else {"unit_more": [unit_more], "more": [more]}
    return look_at_tags(img, np.asarray(corners)[None], spacing, **ring, sharpen=sharpen, max_side_misfit=max_side_misfit, lens=lens)[0]


@functools.lru_cache(maxsize=1)
def _border_mask() -> np.ndarray:
    """(10, 10) bool: the border cells, in the order of :func:`_unit_points`'s border samples."""
    idx = np.arange(CELLS)
    inner = (idx >= BORDER_BITS) & (idx < CELLS - BORDER_BITS)
    return ~(inner[:, None] & inner[None, :])


@functools.lru_cache(maxsize=1)
def _inner_ring() -> np.ndarray:
    """(64,) bool over the border samples of :func:`_unit_points`: those of the border's inner ring."""
    idx = np.arange(CELLS)
    ring = (idx >= 1) & (idx < CELLS - 1)
    inner_ring = ring[:, None] & ring[None, :] & _border_mask()
    return inner_ring[_border_mask()]


def otsu_splits(x: np.ndarray) -> np.ndarray:
    """The threshold that splits each row of values x (T, n) into two classes of least summed
    variance (Otsu): the midpoint between the two values it falls between. -> (T,)"""
    s = np.sort(x, 1)
    n = s.shape[1]
    k = np.arange(1, n)
    c1 = np.cumsum(s, 1)[:, :-1]
    c2 = np.cumsum(s**2, 1)[:, :-1]
    t1, t2 = s.sum(1, keepdims=True), (s**2).sum(1, keepdims=True)
    within = (c2 - c1**2 / k) + ((t2 - c2) - (t1 - c1) ** 2 / (n - k))
    i = np.argmin(within, 1)[:, None]
    return ((np.take_along_axis(s, i, 1) + np.take_along_axis(s, i + 1, 1)) / 2)[:, 0]


def otsu_split(x: np.ndarray) -> float:
    """:func:`otsu_splits` of one set of values x (n,)."""
    return float(otsu_splits(np.asarray(x)[None])[0])


def decode_many(white: np.ndarray) -> list[tuple[int, int, int]]:
    """The tag36h11 code nearest to each row of lattice-order data cells (T, 36) bool (True:
    white) over the four turns: [(id, turn index, Hamming distance)] (the first turn, then the
    lowest id, where several are as near)."""
    if not len(white):
        return []
    # Each turn's page-order bits packed into one integer: Hamming distance = popcount(xor),
    # (T, turns, codes) in integer arithmetic (a +-1 matrix product took BLAS threads: 1-60 ms
    # for a frame's few dozen tags, as busy as the machine was).
    turns = np.stack([page_order(np.asarray(white, bool), m) for m in range(len(TURNS))], 1)  # (T, turns, 36)
    dist = np.bitwise_count(_packed(turns)[:, :, None] ^ _packed(_codes() > 0)[None, None, :])
    flat = dist.reshape(len(turns), -1).argmin(1)  # turn-major: the first turn's nearest code first
    turn, tag = np.divmod(flat, dist.shape[2])
    return [(int(t), int(m), int(dist[r, m, t])) for r, (m, t) in enumerate(zip(turn.tolist(), tag.tolist()))]


def _packed(bits: np.ndarray) -> np.ndarray:
    """36 data cells (..., 36) bool (True: white) as one integer (...) uint64, cell k at bit k."""
    return (bits.astype(np.uint64) << np.arange(36, dtype=np.uint64)).sum(-1, dtype=np.uint64)


def decode_bits(white: np.ndarray) -> tuple[int, int, int]:
    """The tag36h11 code nearest to lattice-order data cells (36,) bool (True: white) over the
    four turns: (id, turn index, Hamming distance)."""
    return decode_many(np.asarray(white)[None])[0]


@dataclass
class TagCell:
    cell: tuple[int, int]  # lattice cell (a, b) of the tag (both even)
    look: TagLook
    tag: int  # nearest tag36h11 id
    turn: int  # its turn (index into TURNS)
    hamming: int  # bits that differ from it
    clean: bool  # a black border inside white gaps: only such cells place and verify the board
    side: float  # px, the tag's shortest side
    # px, the mean of its four corners (one tag read in several lattices is one tag); origin: code, not a threshold (a placeholder:
    # read_cells always gives it)
    centre: tuple[float, float] = (0.0, 0.0)

    @property
    def key(self) -> tuple[int, int, int]:
        """The tag as read and where (its id, its centre to the pixel): counted once however many lattices read it."""
        return (self.tag, round(self.centre[0]), round(self.centre[1]))


def read_cells(lat: Lattice, img: np.ndarray, spacing: float, cfg: TagConfig, lens: EquidistantLens | None = None) -> list[TagCell]:
    """Every tag cell of the lattice (a, b both even) with its four corners, data cells of at least
    ``cfg.min_cell_px`` and all samples in the image, read; ``clean`` says whether it looks like a
    tag (its white gap lighter than its black border, ``cfg.min_clean``)."""
    where = lat.where
    pos = {-1: -spacing, 0: 0.0, 1: 1.0, 2: 1.0 + spacing}
    found: list[tuple[tuple[int, int], np.ndarray, float]] = []  # (cell, corners, shortest side)
    unit_more, more = [], []
    for a, b in where:
        if a % 2 or b % 2:
            continue
        ks = [where.get(t) for t in ((a, b), (a + 1, b), (a + 1, b + 1), (a, b + 1))]
        if None in ks:
            continue
        c = lat.xy[ks]
        side = shortest_side(c)
        if side / CELLS < cfg.min_cell_px:
            continue
        # The lattice corners around the tag (a 4 x 4 patch of the lattice without the tag's own).
        ring = [(i, j) for i in (-1, 0, 1, 2) for j in (-1, 0, 1, 2) if not (0 <= i <= 1 and 0 <= j <= 1) and (a + i, b + j) in where]
        found.append(((a, b), c, side))
        unit_more.append(np.array([(pos[i], pos[j]) for i, j in ring]).reshape(-1, 2))
        more.append(lat.xy[[where[(a + i, b + j)] for i, j in ring]].reshape(-1, 2))
    if not found:
        return []
    corners = np.stack([c for _, c, _ in found])
    looks = look_at_tags(img, corners, spacing, unit_more, more, sharpen=cfg.sharpen, max_side_misfit=cfg.max_side_misfit, lens=lens)
    read = [k for k, look in enumerate(looks) if look is not None]
    codes = decode_many(np.array([looks[k].white for k in read]).reshape(-1, 36))
    out = []
    for k, (tag, turn, ham) in zip(read, codes):
        cell, c, side = found[k]
        look = looks[k]
        ok = look.contrast >= 0 and look.clean >= cfg.min_clean
        out.append(TagCell(cell, look, tag, turn, ham, ok, side, tuple(c.mean(0).tolist())))
    return out
