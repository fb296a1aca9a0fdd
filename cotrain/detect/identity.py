"""Identity: which board corner every lattice corner is.

The lattice (:class:`cotrain.detect.lattice.Lattice`) is placed on the board by one of the four
in-plane rotations (:data:`ROTATIONS`; a board seen from its printed side is never mirrored) and
an integer offset. :func:`assign_ids` scores every placement by

- the network's column / row log-probabilities at the corners (:func:`corner_votes`);
- the checker colour of every lattice cell (:func:`cell_darkness`): square (i, j) of corners is
  black when i + j is even;
- the board's white margin where the lattice stops (:func:`edge_evidence`);

and the best one wins if it beats the runner-up by a margin. A board that looks the same turned
(``Checkerboard.symmetries``, like 7 x 5 squares) is identified up to that turn, and
:func:`canonical_ids` puts corner 0 nearest the image's top left.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.lattice import STEPS, Lattice, next_step
from cotrain.detect.sampling import diag_contrast, edge_contrasts, value_at, values_at
from cotrain.geometry.letterbox import CELLS, Letterbox
from cotrain.targets.checkerboard import ROTATIONS, Checkerboard


def canonical_ids(ids: np.ndarray, xy: np.ndarray, board: Checkerboard) -> np.ndarray:
    """For a symmetric board (``board.symmetries()``), the one of the equivalent id assignments
    that puts corner 0 nearest the image's top left (smallest x + y, where an affine fit of the
    corners' positions to their board coordinates places it), as OpenCV orders them; ids (K,)
    with -1 off the board, xy (K, 2) pixels."""
    perms = board.symmetries()
    on = ids >= 0
    if not perms or on.sum() < 3:
        return ids

    def corner0(v: np.ndarray) -> float:
        A = np.concatenate([board.ij_of(v), np.ones_like(v)[:, None]], 1).astype(np.float64)
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


# --------------------------------------------------------------------------------------------
# Evidence
# --------------------------------------------------------------------------------------------
def corner_votes(lat: Lattice, logp: np.ndarray, offset: np.ndarray, box: Letterbox, cfg: GridConfig) -> np.ndarray:
    """Log-probabilities (K, C) of a dense column / row map ``logp`` (C, h, w) (1/4 processing
    resolution) for every lattice corner: the mean over the corner and the four points
    ``cfg.vote_offset`` of a step away along the diagonals (all of them are nearest to this
    corner, so all share its column and row). ``lat.xy`` + ``offset`` (2,) are input pixels;
    ``scale``: processing pixels per input pixel."""
    where = lat.where
    K = len(lat.ab)
    # Column 0: the corner; 1-4: towards the diagonal neighbours' cells where both sides are known.
    n1, n2 = np.zeros((K, 4), int), np.zeros((K, 4), int)
    have = np.zeros((K, 5), bool)
    have[:, 0] = True
    for k, (a, b) in enumerate(lat.ab.tolist()):
        for i, (da, db) in enumerate(((1, 1), (1, -1), (-1, 1), (-1, -1))):
            m1, m2 = where.get((a + da, b)), where.get((a, b + db))
            if m1 is not None and m2 is not None:
                n1[k, i], n2[k, i], have[k, i + 1] = m1, m2, True
    xy = lat.xy[:, None]
    pts = np.concatenate([xy, xy + cfg.vote_offset * (lat.xy[n1] - xy) + cfg.vote_offset * (lat.xy[n2] - xy)], 1)  # (K, 5, 2)
    votes = CELLS.sample(logp, box.to_processing(pts.reshape(-1, 2) + offset)).reshape(K, 5, -1).astype(np.float64)
    return (votes * have[..., None]).sum(1) / have.sum(1)[:, None]


def cell_darkness(blur: np.ndarray, lat: Lattice) -> dict[tuple[int, int], float]:
    """Per lattice cell (a, b) with all four corners known: +1 darker than its neighbour cells,
    -1 lighter (0 when it has no neighbour cell). Cell (a, b) is spanned by (a, b) .. (a+1, b+1).
    ``blur``: the (H, W) image blurred by 1 px."""
    where = lat.where
    val = {}
    for (a, b), k in where.items():
        quad = [where.get(t) for t in ((a + 1, b), (a, b + 1), (a + 1, b + 1))]
        if None in quad:
            continue
        c = lat.xy[[k, *quad]].mean(0)
        val[(a, b)] = value_at(blur, c)
    out = {}
    for (a, b), v in val.items():
        nbs = [val[t] for t in ((a + 1, b), (a - 1, b), (a, b + 1), (a, b - 1)) if t in val]
        out[(a, b)] = float(np.sign(np.mean(nbs) - v)) if nbs else 0.0
    return out


# origin: sampling (0.3-1.95 steps out, 0.05 apart, around the 0.7-1.6 steps where the last squares end under perspective and the
# fisheye: the tuning log, grid pass, the white margin; set in d242238, "Grid pass: margin evidence from two outward profiles")
EDGE_T = np.arange(0.3, 2.0, 0.05)  # outward profile positions, in lattice steps


def _edge_jobs(lat: Lattice, cfg: GridConfig) -> list[tuple]:
    """The boundary corners :func:`edge_evidence` profiles: (k, da, db, p, out_step, across) for
    corner k whose neighbour (a + da, b + db) is missing, at p (2,), with the image steps outwards
    and sideways (2,) each."""
    where = lat.where
    jobs = []  # (k, da, db, p, out_step, across)
    for (a, b), k in where.items():
        for da, db in STEPS:
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
                out_step = last = lat.xy[k] - lat.xy[back]
                back2 = where.get((a - 2 * da, b - 2 * db))
                if back2 is not None:  # the step the squares would take next (they shrink fast towards a rim)
                    pred = next_step(lat.xy[back] - lat.xy[back2], out_step)
                    if np.hypot(pred[0], pred[1]) >= cfg.large_square_px:
                        out_step = pred
            if any(m is not None for m in side):
                m = next(m for m in side if m is not None)
                sgn = 1.0 if m == side[0] else -1.0
                across = sgn * (lat.xy[m] - lat.xy[k])
                if back is None:
                    out_step = -rot90(across) if da else rot90(across)
            else:  # sideways the squares keep the last step's size (they shrink outwards)
                across = rot90(last) if da else -rot90(last)
            jobs.append((k, da, db, lat.xy[k], out_step, across))
    return jobs


def edge_evidence(
    blur: np.ndarray, lat: Lattice, cfg: GridConfig | None = None, candidates: np.ndarray | None = None
) -> list[tuple[int, int, int, float]]:
    """Where the lattice stops because the board does: (k, da, db, e) for boundary corner k whose
    neighbour (a + da, b + db) is missing, e in [0, 1] the evidence that the squares end one
    square further on and the white margin follows. ``blur``: the (H, W) image blurred by 1 px.

    Beyond the last corner row there is one more row of squares, then the margin. Two profiles run
    outwards from the corner, half a square to either side: they differ across the last squares
    (one black, one white, by ``cfg.min_edge_contrast`` at least), and where the squares end
    (``cfg.edge_end_min`` .. ``cfg.edge_end_max`` steps out: perspective and the fisheye change
    the step) both turn white, and stay white over the band ``cfg.margin_band_start`` ..
    ``cfg.margin_band_end`` beyond. Where the board goes on (occlusion, image edge, rim)
    the profiles keep differing, or turn dark, and there is no evidence. The outward step is the
    one the lattice line would take next (:func:`cotrain.detect.lattice.next_step` from the two
    steps behind: towards a fisheye's rim the last square can be 0.6 of the step before it, and the
    line bends) where that is ``cfg.large_square_px`` long at least (the ratio of shorter,
    blurred steps is noise), else the last step; the sideways step comes from a neighbour across.
    Where one of them is missing (a lattice one corner deep, a corner at a tip) it is the other
    turned by 90 degrees (lattice axes have a x b > 0 in the image).

    Nor is there evidence where the board visibly goes on (:func:`board_goes_on`): one of the
    X-junction ``candidates`` (M, 2) lies where the next corner would, with the checker edge
    running to it. Where the squares grow fast (a board close to the lens) the predicted step falls
    short, and the last black square's side, bending away from the profile, passed for its end.
    """
    cfg = cfg or GridConfig()
    jobs = _edge_jobs(lat, cfg)
    if not jobs:
        return []
    p = np.array([j[3] for j in jobs])[:, None, None, :]
    o = np.array([j[4] for j in jobs])[:, None, None, :]
    c = np.array([j[5] for j in jobs])[:, None, None, :]
    g = np.array([0.5, -0.5])[None, None, :, None]
    prof = values_at(blur, p + EDGE_T[None, :, None, None] * o + g * c)  # (J, T, 2)
    out = []
    i_half = int(np.argmin(np.abs(EDGE_T - 0.5)))
    for n, (k, da, db, *_rest) in enumerate(jobs):
        A, B = prof[n, :, 0], prof[n, :, 1]
        seen = np.cumprod(~(np.isnan(A) | np.isnan(B))).astype(bool)  # the profiles up to the image's edge
        if not seen[i_half]:
            continue
        diff = (A - B) * np.sign(A[i_half] - B[i_half])
        contrast = diff[i_half]
        if contrast < cfg.min_edge_contrast:
            continue
        ended = np.nonzero(seen & (EDGE_T > 0.5) & (diff < 0.5 * contrast))[0]
        if not len(ended) or not cfg.edge_end_min <= EDGE_T[ended[0]] <= cfg.edge_end_max:
            continue
        t_end = EDGE_T[ended[0]]
        band = (EDGE_T >= t_end + cfg.margin_band_start) & (EDGE_T <= t_end + cfg.margin_band_end)  # inside the margin
        white = max(A[i_half], B[i_half]) - 0.5 * contrast
        if not seen[band].all() or not band.any() or min(A[band].min(), B[band].min()) < white:
            continue
        if np.median(np.concatenate([A[band], B[band]])) > max(A[i_half], B[i_half]) + cfg.margin_max_brighter * contrast:
            continue  # far brighter than the white squares: no paper of theirs, a light occluder or the scene
        bright = np.sign(A[i_half] - B[i_half]) * jobs[n][5]  # towards the brighter of the last two squares
        if candidates is not None and board_goes_on(blur, lat.xy[k], jobs[n][4], jobs[n][5], bright, candidates, contrast, cfg):
            continue
        out.append((k, da, db, float(np.clip(1 - np.abs(A[band] - B[band]).mean() / contrast, 0, 1))))
    return out


def board_goes_on(
    blur: np.ndarray,
    p: np.ndarray,
    step: np.ndarray,
    across: np.ndarray,
    bright: np.ndarray,
    candidates: np.ndarray,
    contrast: float,
    cfg: GridConfig,
) -> bool:
    """Whether the checker board goes on from corner p (2,) along ``step`` (2,), the step its
    lattice line would take next (``cfg.large_square_px`` long at least: under motion blur the
    smear of small squares makes junctions in the margin): one of ``candidates`` (M, 2) lies
    where the walk looks for the next corner (``cfg.walk_min_steps`` to ``cfg.walk_max_steps`` steps
    out within ``cfg.walk_angle`` of the step's direction), and the segment to it runs along the edge of the two squares beside it
    (:func:`cotrain.detect.sampling.edge_contrasts` a tenth of its length to either side: the side
    of ``bright`` (2,), where the brighter square lies, brighter by ``cfg.goes_on_min_contrast`` of
    their ``contrast`` at a quarter, half and three quarters of the way), and its checker colours
    alternate against p's, by ``cfg.goes_on_min_alternation`` of p's quadrant contrast (``across``
    (2,): the lattice step across at p). Beyond the board's last corner the segment crosses the
    white margin, where both sides are white, and a junction there (a blurred square's smear, a
    pattern behind the board) keeps no checker colours with p; where the last squares' side meets
    the margin, two of the four quadrants are margin, and the colours alternate by half."""
    step_len = float(np.hypot(step[0], step[1]))
    if not len(candidates) or step_len < cfg.large_square_px:
        return False
    w = candidates - p
    dist = np.hypot(w[:, 0], w[:, 1])
    cos = (w @ step) / np.maximum(dist * step_len, 1e-9)
    near = (dist >= cfg.walk_min_steps * step_len) & (dist <= cfg.walk_max_steps * step_len) & (cos >= np.cos(np.radians(cfg.walk_angle)))
    par = diag_contrast(blur, p, step, across, cfg.diag_offset) if near.any() else 0.0
    for j in np.nonzero(near)[0]:
        o = np.array([-w[j, 1], w[j, 0]]) / dist[j]
        c = edge_contrasts(blur, p, candidates[j], o if o @ bright > 0 else -o, 0.1 * dist[j])
        if not (np.all(np.isfinite(c)) and np.all(c >= cfg.goes_on_min_contrast * contrast)):
            continue
        pc = diag_contrast(blur, candidates[j], w[j], across * (dist[j] / step_len), cfg.diag_offset)
        if pc * par < 0 and abs(pc) >= cfg.goes_on_min_alternation * abs(par):
            return True
    return False


# --------------------------------------------------------------------------------------------
# Placement
# --------------------------------------------------------------------------------------------
class Placement(NamedTuple):
    """The lattice placed on the board (see :func:`assign_ids`)."""

    ids: np.ndarray  # (K,) corner ids, -1 where the placement puts a corner off the board
    score: float  # the best placement's score (nats)
    margin: float  # over the best placement that gives any corner another id (turns of a symmetric board excepted)
    violated: float  # margin evidence the best placement contradicts (corners' worth)
    geometry_margin: float  # the margin from colours, margin evidence and extent alone (no network votes)


def _turn_scores(
    ab: np.ndarray,
    R: np.ndarray,
    lc: np.ndarray,
    lr: np.ndarray,
    pen: np.ndarray,
    cells: np.ndarray,
    dsign: np.ndarray,
    board: Checkerboard,
    cfg: GridConfig,
    edges: list[tuple[int, int, int, float]] | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`assign_ids`'s scores of the lattice ``ab`` (K, 2) turned by ``R`` (2, 2), at every
    offset: total (n_oi, n_oj), the geometry's part of it (n_oi, n_oj), and the offsets ois
    (n_oi,), ojs (n_oj,). ``lc``, ``lr``: the floored column / row log-probabilities; ``pen`` (K,):
    each corner's off-board penalty; ``cells`` (C, 2), ``dsign`` (C,): cell darkness."""
    nx, ny = board.nx, board.ny
    ij0 = ab @ R.T  # (K, 2) before the offset
    # Column score for every offset oi: sum_k lc[k, i_k + 1], i_k = ij0[k, 0] + oi (off-board -> floor).
    ois = np.arange(-ij0[:, 0].max() - 1, nx - ij0[:, 0].min() + 1)
    ojs = np.arange(-ij0[:, 1].max() - 1, ny - ij0[:, 1].min() + 1)
    ii = ij0[:, 0][:, None] + ois[None]  # (K, n_oi)
    jj = ij0[:, 1][:, None] + ojs[None]
    sc = np.where((ii >= 0) & (ii < nx), np.take_along_axis(lc, np.clip(ii + 1, 0, nx + 1), 1), -pen[:, None]).sum(0)
    sr = np.where((jj >= 0) & (jj < ny), np.take_along_axis(lr, np.clip(jj + 1, 0, ny + 1), 1), -pen[:, None]).sum(0)
    off_c = -(pen[:, None] * ((ii < 0) | (ii >= nx))).sum(0)  # the geometry's part of sc, sr
    off_r = -(pen[:, None] * ((jj < 0) | (jj >= ny))).sum(0)
    # Parity: the cell's min corner after rotation decides its colour; black when i + j even.
    par = np.zeros(2)
    if len(cells):
        quad = np.stack([cells, cells + [1, 0], cells + [0, 1], cells + [1, 1]], 1) @ R.T  # (C, 4, 2)
        mn = quad.min(1).sum(1)  # i0 + j0 without offset
        for e in (0, 1):  # e = (oi + oj) mod 2
            black = ((mn + e) % 2) == 0
            par[e] = cfg.parity_weight * float((np.where(black, 1.0, -1.0) * dsign).sum())
    total = sc[:, None] + sr[None, :] + par[(ois[:, None] + ojs[None, :]) % 2]
    geo = off_c[:, None] + off_r[None, :] + par[(ois[:, None] + ojs[None, :]) % 2]
    if edges:
        # Margin evidence: the missing outward neighbour must fall off the board.
        kk = np.array([e[0] for e in edges])
        t0 = (ab[kk] + np.array([[e[1], e[2]] for e in edges])) @ R.T  # (E, 2) before the offset
        ev = np.array([e[3] for e in edges])
        ti = t0[:, 0, None, None] + ois[None, :, None]
        tj = t0[:, 1, None, None] + ojs[None, None, :]
        off = (ti < 0) | (ti >= nx) | (tj < 0) | (tj >= ny)  # (E, n_oi, n_oj)
        margin_term = cfg.edge_weight * (ev[:, None, None] * np.where(off, 1.0, -1.0)).sum(0)
        total = total + margin_term
        geo = geo + margin_term
    return total, geo, ois, ojs


def assign_ids(
    ab: np.ndarray,
    logp_col: np.ndarray,
    logp_row: np.ndarray,
    dark: dict[tuple[int, int], float],
    board: Checkerboard,
    cfg: GridConfig,
    edges: list[tuple[int, int, int, float]] | None = None,
    extent_weight: np.ndarray | None = None,
) -> tuple[np.ndarray, float, float, float]:
    """Place the lattice on the board.

    Args:
        ab: (K, 2) lattice coordinates; logp_col: (K, nx + 2) / logp_row: (K, ny + 2) the network's
        log-probabilities of the corner column -1 .. nx / row -1 .. ny at each corner;
        dark: cell darkness (see :func:`cell_darkness`); board: the checkerboard (nx x ny inner
        corners); edges: margin evidence (see :func:`edge_evidence`); extent_weight: (K,) each
        corner's weight as evidence of the board's extent, times ``cfg.offboard_penalty`` where a
        placement puts it off the board (None: 1 for all).
    Returns a :class:`Placement`: ids (K,) (-1 where the placement puts a corner off the board),
    best score, margin over the best placement that gives any corner another id (turns of a
    symmetric board, see ``board.symmetries()``, do not count), the margin evidence the best
    placement contradicts (sum of e over corners whose missing outward neighbour it puts on the
    board: large when the lattice is a whole board of another size), and the margin of the best
    placement under the geometry's terms alone (over the placement the geometry ranks next).
    """
    nx, ny = board.nx, board.ny
    lc = np.maximum(logp_col, cfg.logp_floor)
    lr = np.maximum(logp_row, cfg.logp_floor)
    cells = np.array(list(dark.keys()), int).reshape(-1, 2)
    dsign = np.array(list(dark.values()))
    pen = cfg.offboard_penalty * (np.ones(len(ab)) if extent_weight is None else extent_weight)  # (K,)
    scored = [_turn_scores(ab, R, lc, lr, pen, cells, dsign, board, cfg, edges) for R in ROTATIONS]  # per turn
    # Every placement (turn r, offsets oi, oj) in the order turn, oi, oj, then best score first (a
    # stable sort: ties keep that order).
    totals = np.concatenate([t.ravel() for t, _, _, _ in scored])
    geos = np.concatenate([g.ravel() for _, g, _, _ in scored])
    turns = np.concatenate([np.full(t.size, r) for r, (t, _, _, _) in enumerate(scored)])
    offs_i = np.concatenate([np.repeat(oi, len(oj)) for _, _, oi, oj in scored])
    offs_j = np.concatenate([np.tile(oj, len(oi)) for _, _, oi, oj in scored])
    order = np.argsort(-totals, kind="stable")
    best = int(order[0])

    def ids_of(n: int) -> np.ndarray:
        return board.id_of(ab @ ROTATIONS[turns[n]].T + [offs_i[n], offs_j[n]])

    ids = ids_of(best)
    # On a symmetric board the turned placements give the same view: they are not competitors.
    on = ids >= 0
    same = [ids] + [np.where(on, perm[np.where(on, ids, 0)], -1) for perm in board.symmetries()]
    runner = next((int(n) for n in order[1:] if not any(np.array_equal(ids_of(n), v) for v in same)), None)
    margin = float(totals[best] - totals[runner]) if runner is not None else np.inf
    # The same margin from the geometry alone (colours, margin evidence, extent; no network votes).
    by_geo = order[1:][np.argsort(-geos[order[1:]], kind="stable")]
    geo_runner = next((int(n) for n in by_geo if not any(np.array_equal(ids_of(n), v) for v in same)), None)
    geo_margin = float(geos[best] - geos[geo_runner]) if geo_runner is not None else np.inf
    violated = 0.0
    for k, da, db, e in edges or []:
        i, j = (ab[k] + [da, db]) @ ROTATIONS[turns[best]].T + [offs_i[best], offs_j[best]]
        violated += e if (0 <= i < nx and 0 <= j < ny) else 0.0
    return Placement(ids, float(totals[best]), margin, violated, geo_margin)
