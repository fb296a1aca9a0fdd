"""Whole boards on the real fisheye checkerboard frames of ``../shared/real``, ours against OpenCV.

    python -m calib_eval.detection.real_frames [--out docs/results/real_frames.json]

For each set (the board is known, no corner is annotated): how many frames each detector finds
the whole board in, and the frames where ``cv2.findChessboardCornersSB`` (or the classic
``findChessboardCorners``) finds the whole board and ours does not. A whole board is every inner
corner, each reported once. Where both find it, the largest distance between ours and OpenCV's
corners (under the board's symmetries, OpenCV's ids taken row-major) says whether they are the
same corners (the classic detector's corners are not refined: its users call cornerSubPix).
No threshold was set on these frames, but `right-0000.png` of the stereo head is what the
removal of the half-resolution gate (2026-12-07) was made for.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from cotrain.io.detections import write_json_atomic
from cotrain.progress import progress_bar

HERE = Path(__file__).resolve().parents[2]
REAL = HERE.parent / "shared" / "real"


@dataclass(frozen=True)
class RealSet:
    """One folder of real frames of a known checkerboard."""

    folder: str  # below ../shared/real
    pattern: str  # the frames' file names (glob)
    squares_x: int  # squares across the board
    squares_y: int  # squares down the board


SETS = (
    RealSet("boofcv_fisheye_chessboard/images", "*.jpg", 5, 7),
    RealSet("ros_fisheye_stereo/images", "*.png", 9, 7),
)


def _opencv(grey: np.ndarray, inner: tuple[int, int], sb: bool) -> np.ndarray | None:
    """OpenCV's corners (K, 2) row-major where it finds the whole board, else None."""
    if sb:
        ok, c = cv2.findChessboardCornersSB(grey, inner)
    else:
        ok, c = cv2.findChessboardCorners(grey, inner, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
    return c.reshape(-1, 2).astype(np.float64) if ok else None


def _agreement_px(ours: np.ndarray, theirs: np.ndarray, nx: int, ny: int) -> float:
    """Largest distance between two whole boards' corners (K, 2), over the id orders OpenCV may
    give the same board in (its own start corner is any of the four)."""
    g = theirs.reshape(ny, nx, 2)
    orders = [g, g[::-1, ::-1]]
    if nx == ny:
        orders += [np.rot90(g, 1), np.rot90(g, 3)]
    orders += [o[::-1] for o in orders] + [o[:, ::-1] for o in orders]
    return float(min(np.abs(np.linalg.norm(o.reshape(-1, 2) - ours, axis=1)).max() for o in orders))


def evaluate_set(s: RealSet, progress: bool = True, detector=None) -> dict:
    """Whole boards found by each detector on one set, and the frames where OpenCV is ahead;
    ours is ``detector`` (default ``Detector`` of the set's board)."""
    from cotrain.detect.detector import Detector
    from cotrain.detect.images import load_image
    from cotrain.targets import Checkerboard, TargetConfig

    board = Checkerboard(TargetConfig(squares_x=s.squares_x, squares_y=s.squares_y))
    det = detector or Detector(target=board, threads=1)
    nx, ny = board.nx, board.ny
    frames = sorted((REAL / s.folder).glob(s.pattern))
    rows = []
    for p in progress_bar(frames, desc=s.folder.split("/")[0], unit="img", enabled=progress):
        grey8 = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        found = det.detect(load_image(p))
        whole = len(found.ids) == board.n_corners and len(set(found.ids.tolist())) == board.n_corners
        row = {"frame": p.name, "ours": int(len(found.ids)), "ours_whole": bool(whole)}
        for name, sb in (("sb", True), ("classic", False)):
            c = _opencv(grey8, (nx, ny), sb)
            row[f"{name}_whole"] = c is not None
            if c is not None and whole:
                row[f"{name}_agree_px"] = _agreement_px(found.xy[np.argsort(found.ids)], c, nx, ny)
        rows.append(row)
    behind = {name: [r["frame"] for r in rows if r[f"{name}_whole"] and not r["ours_whole"]] for name in ("sb", "classic")}
    agree = {name: [r[f"{name}_agree_px"] for r in rows if f"{name}_agree_px" in r] for name in ("sb", "classic")}
    return {
        "set": s.folder,
        "board": f"{s.squares_x} x {s.squares_y} squares",
        "frames": len(rows),
        "whole": {name: sum(r[f"{name}_whole"] for r in rows) for name in ("ours", "sb", "classic")},
        "opencv_whole_ours_not": behind,
        "worst_agreement_px": {name: max(a) if a else float("nan") for name, a in agree.items()},
        "per_frame": rows,
    }


def _table(results: list[dict]) -> str:
    lines = [
        "| set | frames | whole boards: ours / SB / classic | SB whole, ours not | classic whole, ours not "
        "| largest difference from SB / classic where both (px) |",
        "| --- | --- | --- | --- | --- | --- |",
    ]
    for r in results:
        w, b, d = r["whole"], r["opencv_whole_ours_not"], r["worst_agreement_px"]
        lines.append(
            f"| {r['set']} | {r['frames']} | {w['ours']} / {w['sb']} / {w['classic']} | {', '.join(b['sb']) or 'none'} "
            f"| {', '.join(b['classic']) or 'none'} | {d['sb']:.2f} / {d['classic']:.2f} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.detection.real_frames", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, help="write the figures as JSON here")
    args = ap.parse_args(argv)
    sets = [s for s in SETS if (REAL / s.folder).is_dir()]
    if not sets:
        print(f"real_frames: no real frames under {REAL} (../shared/real beside the checkout)", file=sys.stderr)
        return 2
    results = [evaluate_set(s) for s in sets]
    print(_table(results))
    if args.out:
        write_json_atomic(results, args.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
