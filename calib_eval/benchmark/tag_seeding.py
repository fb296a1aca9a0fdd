"""Can cv2.aruco seed the AprilGrid's tag pass? Issue 64's first suggestion for the pass's speed, measured.

    python -m calib_eval.benchmark.tag_seeding [--runs 3] [--json docs/results/tag_seeding.json]

On the frames ``make bench`` times the tag pass on (every other FoV-row frame of the AprilGrid
evaluation set, 1280x720, :func:`calib_eval.benchmark.timing.bench_tags`), per FoV:

- **aruco alone**: the detectable corners whose tags cv2.aruco decodes (``DICT_APRILTAG_36h11``,
  Kalibr's 2-bit border, as the AprilGrid evaluation runs it; a tag's four corners get Kalibr's
  ids by :data:`ARUCO_TO_KALIBR`), the corners it puts more than ``TOL_PX`` from their labels, and
  the frames where it decodes a tag of the board at all;
- **seeded**: on the frames aruco decodes a tag in, the pass that would skip the full-image search
  (:func:`seeded_pass`): the decoded corners fitted as saddles, checked against the print
  (:func:`cotrain.detect.verification.print_check`) and completed from there
  (:func:`cotrain.detect.completion.complete_board`, no candidates); its recall and wrong corners
  beside the tag pass's on the same frames, the frames it completes (no corner it predicts in view
  left unfound: where it could stand alone), and the time of each (median over ``runs`` runs of the
  mean per frame, both in the same run, aruco's own time included in the seeded pass's).

The write-up is docs/results/tag_seeding.md. No part of this is in the detector.
"""

from __future__ import annotations

import argparse
import json
import statistics
import time
from pathlib import Path

import cv2
import numpy as np

from calib_eval.detection.tags import PEERS, TagEvalConfig, render_set, score_frame
from cotrain.detect.buffers import keep_image_buffers
from cotrain.detect.completion import complete_board
from cotrain.detect.detector import Detector
from cotrain.detect.saddle import fit_saddles, smooth_cached
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_pass import circle_crop
from cotrain.detect.verification import print_check
from cotrain.targets import TargetConfig, make_target
from cotrain.targets.aprilgrid import AprilGrid

# cv2.aruco's corner k of a tag (its bitmap's top left, top right, bottom right, bottom left) is
# Kalibr's corner ARUCO_TO_KALIBR[k] of AprilGrid.tag_corners (bottom left, bottom right, top right,
# top left on the page): on this repo's boards the bitmap's first row lies at the page's bottom and
# its first column at the page's right. Checked by the script itself: ``aruco_off_px`` counts the
# corners it puts away from their labels (all of them under any other order).
ARUCO_TO_KALIBR = (1, 0, 3, 2)
FIT_HALF_PX = 3  # px: the saddle fit's window half-size at aruco's corners (the tag pass's final window, GridConfig.final_max_half)
MAX_FIT_SHIFT_PX = 3.0  # px: a fit farther than this from aruco's corner is dropped (171 of aruco's 1,592 corners lie over 3 px off)


def aruco_corners(tags: list[tuple[int, np.ndarray]], board: AprilGrid) -> tuple[np.ndarray, np.ndarray]:
    """The corners of the board's tags among aruco's ``tags`` [(id, (4, 2) corners)]: ids (K,) and xy (K, 2)."""
    mine = [(t, c) for t, c in tags if 0 <= t < board.n_tags]
    if not mine:
        return np.zeros(0, int), np.zeros((0, 2))
    ids = np.concatenate([board.tag_corners(t)[list(ARUCO_TO_KALIBR)] for t, _ in mine])
    return ids, np.concatenate([c for _, c in mine]).astype(np.float64)


def seeded_pass(grey: np.ndarray, tags: list[tuple[int, np.ndarray]], board: AprilGrid, cfg: TagConfig):
    """The seeded pass on ``grey`` (H, W) float32 in [0, 1] from aruco's ``tags``: ids (K,), xy (K, 2)
    in the frame's pixels and the corners completion left unfound in view; None where fewer than four
    corners are left to complete from."""
    f, (x0, y0), crop, inside, lens = circle_crop(grey, cfg)
    ids, xy = aruco_corners(tags, board)
    xy = (xy + 0.5) * f - 0.5 - [x0, y0]
    if len(ids) < 4:
        return None
    rim = cv2.distanceTransform(inside.astype(np.uint8), cv2.DIST_L2, 3)
    smoothed: dict[int, np.ndarray] = {}
    q, ok, _ = fit_saddles(crop, smoothed, xy, FIT_HALF_PX, cfg.grid, rim)
    keep = ok & (np.linalg.norm(q - xy, axis=1) < MAX_FIT_SHIFT_PX)
    ids, xy = ids[keep], q[keep]
    lens = lens if cfg.complete.lens else None
    if len(ids) >= 4:
        keep = print_check(smooth_cached(smoothed, crop, 1), rim, board, ids, xy, cfg.complete, lens=lens)
        ids, xy = ids[keep], xy[keep]
    if len(ids) < 4:
        return None
    done = complete_board(crop, smoothed, rim, np.zeros((0, 2)), board, ids, xy, cfg.complete, cfg.grid, lens)
    return done.ids, (done.xy + [x0, y0] + 0.5) / f - 0.5, len(done.unfound)


def measure(runs: int = 3, root: Path = Path("report")) -> dict:
    """The figures of the module's docstring, per FoV and over all frames."""
    keep_image_buffers()
    board = make_target(TargetConfig(kind="aprilgrid"))
    ecfg = TagEvalConfig(per_fov=50, conditions=[], n_empty=0)  # the frames bench_tags times
    out = root / f"tags_{ecfg.seed}_{ecfg.per_fov}"
    labels = [lab for lab in render_set(ecfg, board, out) if lab["fov"]][::2]
    images = [cv2.imread(str(out / "images" / lab["image"]), cv2.IMREAD_GRAYSCALE) for lab in labels]
    aruco, ours, cfg = PEERS["aruco"](), Detector(target=board), TagConfig()
    found = [aruco(img) for img in images]
    seeded_rows = [i for i, tags in enumerate(found) if len(aruco_corners(tags, board)[0])]
    t_seeded, t_ours = [], []
    seeded, detected = {}, {}  # the last run's results, scored below
    for _ in range(max(1, runs)):
        t0 = time.perf_counter()
        for i in seeded_rows:
            seeded[i] = seeded_pass(ours._grey(images[i]), aruco(images[i]), board, cfg)
        t_seeded.append((time.perf_counter() - t0) / max(1, len(seeded_rows)))
        t0 = time.perf_counter()
        for i in seeded_rows:
            detected[i] = ours.detect(images[i])
        t_ours.append((time.perf_counter() - t0) / max(1, len(seeded_rows)))
    rows: dict[str, dict] = {}
    for i, (lab, tags) in enumerate(zip(labels, found)):
        row = rows.setdefault(str(lab["fov"]), dict.fromkeys(_COUNTS, 0))
        ids, xy = aruco_corners(tags, board)
        s = score_frame(ids.tolist(), list(xy), lab, ecfg.min_tag_px)
        row["frames"] += 1
        row["detectable"] += int(s["det"].sum())
        row["aruco_hit"] += int(s["hit"].sum())
        row["aruco_off_px"] += s["wrong"]
        if i not in seeded_rows:
            continue
        row["aruco_frames"] += 1
        d, r = detected[i], seeded[i]
        s_ours = score_frame(d.ids.tolist(), list(d.xy), lab, ecfg.min_tag_px)
        s_seed = score_frame(r[0].tolist(), list(r[1]), lab, ecfg.min_tag_px) if r else {"hit": np.zeros(0), "wrong": 0}
        row["seeded_detectable"] += int(s["det"].sum())
        row["seeded_hit"] += int(s_seed["hit"].sum())
        row["seeded_wrong"] += s_seed["wrong"]
        row["ours_hit"] += int(s_ours["hit"].sum())
        row["ours_wrong"] += s_ours["wrong"]
        row["seeded_complete"] += int(r is not None and r[2] == 0)
    total = {k: sum(r[k] for r in rows.values()) for k in _COUNTS}
    return {
        "per_fov": rows,
        "all": total,
        "ms_seeded": 1000 * statistics.median(t_seeded),
        "ms_ours": 1000 * statistics.median(t_ours),
        "runs": runs,
    }


_COUNTS = (
    "frames",
    "detectable",
    "aruco_hit",
    "aruco_off_px",
    "aruco_frames",
    "seeded_detectable",
    "seeded_hit",
    "seeded_wrong",
    "seeded_complete",
    "ours_hit",
    "ours_wrong",
)


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.tag_seeding", description=__doc__.split("\n")[0])
    ap.add_argument("--runs", type=int, default=3, help="timed runs (median)")
    ap.add_argument("--json", type=Path, help="write the figures here")
    args = ap.parse_args(argv)
    res = measure(args.runs)
    for fov, r in [*res["per_fov"].items(), ("all", res["all"])]:
        print(
            f"FoV {fov}: aruco {r['aruco_hit']}/{r['detectable']} corners ({r['aruco_off_px']} off), "
            f"tags in {r['aruco_frames']}/{r['frames']} frames; seeded {r['seeded_hit']}/{r['seeded_detectable']} "
            f"({r['seeded_wrong']} wrong, {r['seeded_complete']} complete), "
            f"tag pass {r['ours_hit']} ({r['ours_wrong']} wrong)"
        )
    print(f"on the frames aruco seeds: seeded {res['ms_seeded']:.1f} ms, tag pass {res['ms_ours']:.1f} ms (medians of {res['runs']})")
    if args.json:
        args.json.write_text(json.dumps(res, indent=1) + "\n")


if __name__ == "__main__":
    main()
