"""How many detectable corners a detector could identify from the board's geometry alone.

    python -m calib_eval.detection.identifiability [--set report/detection] [--target TARGET.yaml]

A partial view of a checkerboard can be ambiguous: a 4x3 patch of corners at one corner of a
10x7 board looks the same as a 4x3 patch at the opposite corner turned by a half turn if the
colours agree, or at another corner turned by 90 degrees. For every frame of a rendered detection
set (its labels), this asks whether any placement of the seen corners on the board other than the
true one (four in-plane rotations x integer offsets) is consistent with everything an ideal
geometric detector could observe:

- every seen corner lands on the board;
- the checker colour of every cell whose four corners are seen;
- the white margin: where a seen corner's neighbour is off the board in truth and that place is
  in view (inside the image and its image circle: one step beyond the corner, extrapolated from
  the labels), it must be off the board in the other placement too; a margin beyond the image's
  edge is not seen, so it identifies nothing;
- continuation: where a seen corner's neighbour is on the board and visible in the image but not
  among the seen corners, it must be on the board in the other placement too.

"Seen" is either every detectable corner (what the evaluation asks for) or every visible one
(squares too small to be detectable still show the board's extent). The share of detectable
corners in frames with no other consistent placement is a ceiling for a detector that takes
identity from geometry: beyond it, only context the geometry does not pin (the network's guess)
can identify corners, and a guess can be wrong.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from cotrain.targets import (  # the board's in-plane turns, as the detector's placements use them
    ROTATIONS,
    Checkerboard,
    TargetError,
)

STEPS = ((1, 0), (-1, 0), (0, 1), (0, -1))


def off_board_in_view(
    q: np.ndarray, nx: int, ny: int, size: tuple[int, int], centre: np.ndarray | None = None, radius: float | None = None
) -> set[tuple[int, int]]:
    """The off-board grid places (i, j) next to the board's edge corners whose place in the image
    is in view, where an image could show that no corner follows.

    q: (nx * ny, 2) every corner's pixel position (labels); size: (width, height); centre (2,) and
    radius: the image circle, if any. A place's pixel position is one step beyond its edge corner,
    extrapolated along the corner's inward neighbour: 2 q[edge] - q[inward].
    """
    w, h = size
    places = set()
    for k in range(nx * ny):
        i, j = k % nx, k // nx
        for di, dj in STEPS:
            if 0 <= i + di < nx and 0 <= j + dj < ny:
                continue
            if not (0 <= i - di < nx and 0 <= j - dj < ny):
                continue  # a board one corner wide: no inward neighbour to extrapolate from
            p = 2 * q[k] - q[(j - dj) * nx + (i - di)]
            shown = bool(np.isfinite(p).all()) and 0 <= p[0] <= w - 1 and 0 <= p[1] <= h - 1
            if shown and centre is not None and radius is not None:
                shown = float(np.hypot(*(p - centre))) < radius
            if shown:
                places.add((i + di, j + dj))
    return places


def identifiable(seen: np.ndarray, visible: np.ndarray, nx: int, ny: int, margin_in_view: set[tuple[int, int]] | None = None) -> bool:
    """True when the seen corner ids (K,) admit no placement on the nx x ny corner grid other than
    the true one; ``visible`` (nx * ny,) bool marks corners whose presence the image shows;
    ``margin_in_view``: the off-board places the image shows (``off_board_in_view``), None for all."""
    on = lambda t: (t[..., 0] >= 0) & (t[..., 0] < nx) & (t[..., 1] >= 0) & (t[..., 1] < ny)  # noqa: E731
    ij = np.stack([seen % nx, seen // nx], 1)
    have = set(seen.tolist())
    cells = np.array([(i, j) for i, j in ij if {j * nx + i + 1, (j + 1) * nx + i, (j + 1) * nx + i + 1} <= have], int).reshape(-1, 2)
    quad = np.stack([cells, cells + [1, 0], cells + [0, 1], cells + [1, 1]], 1)  # (C, 4, 2)
    colour = quad.min(1).sum(1) % 2  # square colour of each seen cell
    must_off, must_on = [], []  # (corner ij, step): the neighbour must be off / on the board
    for i, j in ij:
        for d in STEPS:
            n = np.array([i + d[0], j + d[1]])
            if not on(n):
                if margin_in_view is None or (int(n[0]), int(n[1])) in margin_in_view:
                    must_off.append((i + d[0], j + d[1]))
            elif visible[n[1] * nx + n[0]] and n[1] * nx + n[0] not in have:
                must_on.append((i + d[0], j + d[1]))
    must_off, must_on = np.array(must_off, int).reshape(-1, 2), np.array(must_on, int).reshape(-1, 2)
    span = nx + ny
    for r, R in enumerate(ROTATIONS):
        for oi in range(-span, span):
            for oj in range(-span, span):
                if r == 0 and oi == 0 and oj == 0:
                    continue
                o = np.array([oi, oj])
                if not on(ij @ R.T + o).all():
                    continue
                if len(cells) and not np.array_equal(((quad @ R.T).min(1).sum(1) + oi + oj) % 2, colour):
                    continue
                if on(must_off @ R.T + o).any() or not on(must_on @ R.T + o).all():
                    continue
                return False
    return True


def ceiling(labels: list[dict], nx: int, ny: int, size: tuple[int, int] | None = None) -> dict:
    """Share of detectable corners in identifiable frames, per FoV (or hard condition) and over the
    FoV rows ("all"), with the detectable corners or all visible ones as what is seen. With the
    image ``size`` (width, height), a margin counts only where it is in view (``off_board_in_view``,
    the labels' corners and image circle); without it, everywhere."""
    acc: dict = {}
    for lab in labels:
        if not lab.get("has_target", True):
            continue
        vis, det = np.asarray(lab["visible"], bool), np.asarray(lab["detectable"], bool)
        n = int(det.sum())
        if not n:
            continue
        in_view = None
        if size is not None and lab.get("corners") is not None:
            centre = np.asarray(lab["centre"], float) if lab.get("centre") is not None else None
            in_view = off_board_in_view(np.asarray(lab["corners"], float), nx, ny, size, centre, lab.get("radius"))
        for key in (lab.get("condition") or lab.get("fov"), "all" if not lab.get("condition") else "all conditions"):
            a = acc.setdefault(key, [0, 0, 0])
            a[0] += n
            a[1] += n * identifiable(np.nonzero(det)[0], vis, nx, ny, in_view)
            a[2] += n * identifiable(np.nonzero(vis)[0], vis, nx, ny, in_view)
    return {str(k): {"detectable": a[0], "from_detectable": a[1] / a[0], "from_visible": a[2] / a[0]} for k, a in acc.items()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.detection.identifiability", description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="report/detection", help="rendered detection set (its labels.json)")
    ap.add_argument("--target", help="the set's board, if its labels.json names none (our target config or a Kalibr yaml)")
    args = ap.parse_args(argv)
    from calib_eval.detection.evaluation import read_set

    try:
        meta, board = read_set(args.set, args.target, default=Checkerboard())
    except TargetError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    if not isinstance(board, Checkerboard):
        print(f"error: identifiability is worked out for checkerboards, not {board.kind}", file=sys.stderr)
        return 2
    cfg = meta.get("config", {})
    size = (cfg["width"], cfg["height"]) if "width" in cfg and "height" in cfg else None
    res = ceiling(meta["labels"], board.nx, board.ny, size)
    anywhere = ceiling(meta["labels"], board.nx, board.ny) if size is not None else res
    print(f"identifiable from geometry alone ({Path(args.set) / 'labels.json'}): share of detectable corners")
    if size is None:
        print("(the set names no image size: margins beyond the image count as seen)")
    print("| FoV | detectable corners | seen = detectable | seen = visible | seen = detectable, margins beyond the view counted too |")
    print("|---|---|---|---|---|")
    for k, v in sorted(res.items(), key=lambda kv: (kv[0] == "all", kv[0])):
        print(f"| {k} | {v['detectable']} | {v['from_detectable']:.3f} | {v['from_visible']:.3f} | {anywhere[k]['from_detectable']:.3f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
