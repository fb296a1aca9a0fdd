"""Recall and wrong ids of the grid pass against its identity-margin threshold.

    python -m calib_eval.detection.tuning [--model M.onnx] [--seed 7] [--set DIR] [--degrade jpeg|blur]
                                     [--size 1280x720] [--grid KEY=VALUE ...]

Renders (or reuses) a detection set with its own seed (tune on a tuning set of
``calib_eval/detection/sets.py``, seed 7 or 11; a set tuned on joins that list; the first line
printed says which kind of set it is), runs the network once per image, runs the grid pass with
no margin threshold (nor the geometry-backed and votes-alone ones of
``cotrain.detect.grid_pass.placement_is_sure``), and prints, per threshold, the recall of
detectable corners and the share of reported corners that are wrong (wrong id or over 3 px off),
plus the margins of the placements that were wrong. ``--grid`` overrides fields of the grid
pass's ``GridConfig`` (``--grid offboard_penalty=20``) to try a change before making it;
``--size`` renders frames of another size (another rig).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import cv2
import numpy as np

from calib_eval.detection.evaluation import EvalConfig, load_or_render, parse_size, score_image
from calib_eval.detection.sets import describe
from cotrain.detect.detector import Detector
from cotrain.detect.grid_config import GridConfig
from cotrain.detect.images import load_image
from cotrain.progress import progress_bar

THRESHOLDS = (6, 8, 10, 12, 15, 18, 20, 22, 25, 30)
DEGRADATIONS = ("none", "jpeg", "blur")


def degrade(grey: np.ndarray, how: str, seed: int = 0) -> np.ndarray:
    """A rendered frame as another camera or renderer might give it: ``jpeg``: gamma 0.8 and JPEG
    quality 70; ``blur``: Gaussian blur of sigma 1.5 px and noise of 4 / 255; ``none``: as is."""
    if how == "none":
        return grey
    if how == "jpeg":
        g8 = np.clip(255 * np.clip(grey, 0, 1) ** 0.8, 0, 255).astype(np.uint8)
        ok, buf = cv2.imencode(".jpg", g8, [cv2.IMWRITE_JPEG_QUALITY, 70])
        return cv2.imdecode(buf, cv2.IMREAD_UNCHANGED).astype(np.float32) / 255
    if how == "blur":
        noise = np.random.default_rng(seed).normal(0, 4 / 255, grey.shape)
        return np.clip(cv2.GaussianBlur(grey, (0, 0), 1.5) + noise, 0, 1).astype(np.float32)
    raise ValueError(f"degradation must be one of {DEGRADATIONS}, not {how!r}")


# The acceptance threshold the table sweeps (min_margin), and the votes alone let place a board (every placement is scored).
SWEPT = {"min_margin": -np.inf, "votes_alone": True}


def grid_overrides(pairs: list[str]) -> dict[str, float | int]:
    """``["key=value", ...]`` -> GridConfig field overrides, each of its field's type. Unknown keys,
    the thresholds the table sweeps or turns off (``SWEPT``) and values of the wrong type are errors."""

    fields = {f.name: type(f.default) for f in dataclasses.fields(GridConfig) if f.name not in SWEPT}
    out = {}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key not in fields:
            raise ValueError(f"--grid wants KEY=VALUE with KEY one of {sorted(fields)}, not {pair!r}")
        try:
            out[key] = _parsed(value, fields[key])
        except ValueError:
            raise ValueError(f"--grid {key}: {value!r} is not a valid {fields[key].__name__}") from None
    return out


def _parsed(value: str, kind: type):
    """``value`` as a ``kind``; a bool from true / false (any case), not from bool(value), which is True for "False"."""
    if kind is bool:
        word = value.strip().lower()
        if word not in ("true", "false"):
            raise ValueError(value)
        return word == "true"
    return kind(value)


def margin_table(
    model: str | None,
    set_dir: Path,
    seed: int,
    progress: bool = True,
    how: str = "none",
    grid: dict | None = None,
    size: tuple[int, int] = (1280, 720),
) -> dict:
    meta = load_or_render(EvalConfig(seed=seed, width=size[0], height=size[1], conditions=[]), set_dir, progress)
    det = Detector(model)
    gcfg = dataclasses.replace(det.grid, **{**(grid or {}), **SWEPT})  # every placement is scored
    rows, total = [], 0
    for n, lab in enumerate(progress_bar(meta["labels"], desc="grid pass", unit="img", enabled=progress)):
        grey = degrade(load_image(set_dir / "images" / lab["image"]), how, seed=n)
        r = det.grid_result(grey, gcfg)
        if not lab["has_target"]:
            rows.append((r.margin, len(r.ids), len(r.ids), 0, 1))
            continue
        pred = [[int(i), float(x), float(y)] for i, (x, y) in zip(r.ids, r.xy)]
        sc = score_image(pred, True, np.array(lab["corners"]), np.array(lab["visible"]), np.array(lab["detectable"]))
        total += sc["n_detectable"]
        rows.append((r.margin, len(r.ids), sc["n_outliers"], len(sc["hits"]), 0))
    a = np.array(rows, float)
    found = ~np.isnan(a[:, 0])
    table = []
    for t in THRESHOLDS:
        sel = found & (a[:, 0] >= t)
        table.append(
            {
                "threshold": t,
                "recall": float(a[sel, 3].sum() / max(1, total)),
                "reported": int(a[sel, 1].sum()),
                "wrong": int(a[sel, 2].sum()),
                "false_images": int((sel & (a[:, 4] > 0) & (a[:, 1] > 0)).sum()),
            }
        )
    wrong_margins = sorted(float(m) for m, n, w, _, _ in rows if n > 0 and w > 0.5 * n)
    kind = describe("checkerboard", seed, *size)
    return {"seed": seed, "set": kind, "degradation": how, "grid": grid or {}, "table": table, "wrong_placement_margins": wrong_margins}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.detection.tuning", description=__doc__.splitlines()[0])
    ap.add_argument("--model", help="ONNX model (default: the shipped model)")
    ap.add_argument("--seed", type=int, default=7, help="set seed (the evaluation's is 2026)")
    ap.add_argument("--set", default="report/tuning", help="folder of the rendered set (reused when it matches)")
    ap.add_argument("--degrade", choices=DEGRADATIONS, default="none", help="degrade the frames first (see degrade())")
    ap.add_argument("--size", default="1280x720", help="image size WIDTHxHEIGHT of the rendered set")
    ap.add_argument("--grid", action="append", default=[], metavar="KEY=VALUE", help="override a GridConfig field")
    args = ap.parse_args(argv)
    try:
        grid = grid_overrides(args.grid)
        size = parse_size(args.size)
    except ValueError as e:
        ap.error(str(e))
    res = margin_table(args.model, Path(args.set), args.seed, how=args.degrade, grid=grid, size=size)
    extra = "" if args.degrade == "none" else f", degraded ({args.degrade})"
    extra += "".join(f", {k}={v:g}" for k, v in grid.items()) + ("" if size == (1280, 720) else f", {args.size}")
    print(res["set"])
    print(f"grid pass on the seed-{args.seed} set{extra}: margin threshold -> recall, wrong among reported")
    for r in res["table"]:
        pct = 100 * r["wrong"] / max(1, r["reported"])
        print(
            f"  {r['threshold']:>3}: recall {r['recall']:.3f}, {r['wrong']}/{r['reported']} wrong ({pct:.2f} %), "
            f"images without target with reports {r['false_images']}"
        )
    print("margins of wrong placements:", " ".join(f"{m:.1f}" for m in res["wrong_placement_margins"]))
    (Path(args.set) / ("margins.json" if args.degrade == "none" else f"margins_{args.degrade}.json")).write_text(json.dumps(res, indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
