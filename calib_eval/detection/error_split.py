"""Where a detector's mean corner error comes from: frames whose corners all sit off their labels by
one common shift, and the rest.

    python -m calib_eval.detection.error_split [--set report/detection] [--target TARGET.yaml]

A frame whose corners are all off their labels by one vector most likely has its labels off, not its
corners: the renderer's motion blur (``RenderConfig.p_motion``, ``motion_direction``) weights the
exposure unevenly along the blur (kornia's ``direction``) and moves the whole image, by up to
(length + 1) / 6 px (1 px for a 5 px blur); labels rendered before ``LABEL_VERSION`` 2 stayed at the blur's middle
(0.7 px off on average in those frames), and this split is how that was found. This runs
the detector for the set's target on every frame, matches its corners to the labels by id (within
3 px) and splits the error: frames with a common shift (the mean offset of at least
``MIN_CORNERS`` corners over ``SHIFT_PX``) and the others, and every corner's error once its
frame's common shift is taken out.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from calib_eval.detection.evaluation import TOL_PX  # a reported corner further than this from its label is not matched (it is wrong)
from calib_eval.detection.tags import TagEvalConfig
from cotrain.progress import progress_bar

MIN_CORNERS = 8  # corners a frame needs for its common shift to be measured
SHIFT_PX = 0.25  # a frame whose corners are off by a common shift longer than this is "shifted"


def split_errors(offsets: dict[str, np.ndarray], min_corners: int = MIN_CORNERS, shift_px: float = SHIFT_PX) -> dict:
    """Error figures from the offsets (reported minus label, (K, 2) px) of each frame's matched
    corners: ``all``, ``shifted`` (frames whose mean offset over at least ``min_corners`` corners is
    longer than ``shift_px``), ``other``, each {frames, corners, mean, median}, and
    ``residual_mean`` / ``residual_median``: every corner's error with its frame's mean offset
    taken out (frames under ``min_corners`` as they are)."""
    groups: dict[str, list[np.ndarray]] = {"all": [], "shifted": [], "other": []}
    frames = {"all": 0, "shifted": 0, "other": 0}
    residual = []
    for d in offsets.values():
        d = np.asarray(d, float).reshape(-1, 2)
        if not len(d):
            continue
        shift = d.mean(0) if len(d) >= min_corners else np.zeros(2)
        key = "shifted" if np.hypot(*shift) > shift_px else "other"
        e = np.hypot(d[:, 0], d[:, 1])
        for k in ("all", key):
            groups[k].append(e)
            frames[k] += 1
        residual.append(np.hypot(*(d - shift).T))
    out = {}
    for k, es in groups.items():
        e = np.concatenate(es) if es else np.zeros(0)
        out[k] = {
            "frames": frames[k],
            "corners": len(e),
            "mean": float(e.mean()) if len(e) else float("nan"),
            "median": float(np.median(e)) if len(e) else float("nan"),
        }
    r = np.concatenate(residual) if residual else np.zeros(0)
    out["residual_mean"] = float(r.mean()) if len(r) else float("nan")
    out["residual_median"] = float(np.median(r)) if len(r) else float("nan")
    return out


def countable(lab: dict) -> np.ndarray:
    """(N,) bool: the corners a frame's recall counts (``detectable`` of a checkerboard set; visible
    with their tag at least ``TagEvalConfig.min_tag_px`` across in an AprilGrid set)."""
    if "detectable" in lab:
        return np.asarray(lab["detectable"], bool)
    return np.asarray(lab["visible"], bool) & (np.asarray(lab["tag_px"], float) >= TagEvalConfig.min_tag_px)


def main(argv: list[str] | None = None) -> int:
    from calib_eval.detection.evaluation import read_set
    from cotrain.detect.detector import make_detector
    from cotrain.detect.images import ImageError, load_image
    from cotrain.targets import TargetError

    ap = argparse.ArgumentParser(prog="python -m calib_eval.detection.error_split", description=__doc__.splitlines()[0])
    ap.add_argument("--set", default="report/detection", help="rendered detection set (its labels.json and images/)")
    ap.add_argument("--target", help="the set's target, if its labels.json names none (our target config or a Kalibr yaml)")
    args = ap.parse_args(argv)
    try:
        meta, target = read_set(args.set, args.target)
    except TargetError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    det = make_detector(target)
    offsets, failed = {}, []
    labels = [lab for lab in meta["labels"] if lab.get("has_target", lab.get("fov") is not None) and not lab.get("condition")]
    for lab in progress_bar(labels, desc="detect", unit="img"):
        try:
            d = det.detect(load_image(Path(args.set) / "images" / lab["image"]))
        except ImageError as e:
            failed.append(f"{lab['image']}: {e}")
            continue
        gt, ok = np.asarray(lab["corners"], float), countable(lab)
        off = d.xy - gt[d.ids] if len(d.ids) else np.zeros((0, 2))
        keep = ok[d.ids] & (np.hypot(off[:, 0], off[:, 1]) <= TOL_PX) if len(d.ids) else np.zeros(0, bool)
        offsets[lab["image"]] = off[keep]
    res = split_errors(offsets)
    print(f"corner error on {args.set} (FoV frames, corners matched within {TOL_PX:g} px of their label):")
    print("| group | frames | corners | mean px | median px |\n|---|---|---|---|---|")
    names = {"all": "all", "shifted": f"with a common shift > {SHIFT_PX} px", "other": "the others"}
    for k in ("all", "shifted", "other"):
        r = res[k]
        print(f"| {names[k]} | {r['frames']} | {r['corners']} | {r['mean']:.3f} | {r['median']:.3f} |")
    print(f"each frame's common shift taken out: mean {res['residual_mean']:.3f} px, median {res['residual_median']:.3f} px")
    for f in failed:
        print(f"skipped {f}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
