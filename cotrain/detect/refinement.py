"""Stage 6, refinement: the reported positions of a placed lattice's corners, fitted once more in a
small window (at most ``GridConfig.final_max_half`` px half-size), close to the junction, where
bent edges and the blooming of real prints pull least. Both passes report through it.
"""

from __future__ import annotations

import math

import numpy as np

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.lattice import STEPS, Lattice
from cotrain.detect.saddle import fit_saddles, window_half


def shortest_steps(lat: Lattice) -> np.ndarray:
    """(K,) px: each corner's shortest step to a lattice neighbour (inf for a corner without one)."""
    where = lat.where
    short = np.full(len(lat.ab), np.inf)
    pts = lat.xy.tolist()  # scalar arithmetic in the per-corner loop
    for (a, b), k in where.items():
        for da, db in STEPS:
            t = (a + da, b + db)
            if t in where:
                short[k] = min(short[k], math.hypot(pts[where[t]][0] - pts[k][0], pts[where[t]][1] - pts[k][1]))
    return short


def final_fits(
    lat: Lattice, grey: np.ndarray, cfg: GridConfig, smoothed: dict[int, np.ndarray], rim_dist: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Every corner fitted once more in a window of at most ``cfg.final_max_half`` (about a third
    of its shortest lattice step below that). Returns xy (K, 2), the fit where it succeeded and
    moved by at most ``cfg.max_refit_shift`` of that step, the old position elsewhere, and which
    corners those are (K,) bool."""
    short = shortest_steps(lat)
    short = np.where(np.isfinite(short), short, 3 * cfg.min_step_px)
    halves = window_half(short, cfg.final_max_half)
    xy, fitted = lat.xy.copy(), np.zeros(len(lat.ab), bool)
    for h in np.unique(halves):
        idx = np.nonzero(halves == h)[0]
        q, ok, _ = fit_saddles(grey, smoothed, lat.xy[idx], int(h), cfg, rim_dist)
        good = ok & (np.linalg.norm(q - lat.xy[idx], axis=1) < cfg.max_refit_shift * short[idx])
        xy[idx[good]] = q[good]
        fitted[idx[good]] = True
    return xy, fitted


def refine_positions(
    lat: Lattice, grey: np.ndarray, cfg: GridConfig, smoothed: dict[int, np.ndarray], rim_dist: np.ndarray | None = None
) -> Lattice:
    """The reported positions (:func:`final_fits`). The search and the checks above need the larger
    windows' robustness; the position is best taken close to the junction, where the bent edges and
    the blooming of real prints pull it least (BoofCV frames: calibration RMS 0.26 -> 0.21 px). A
    corner whose fit fails keeps its position."""
    return Lattice(final_fits(lat, grey, cfg, smoothed, rim_dist)[0], lat.ab, lat.filled)
