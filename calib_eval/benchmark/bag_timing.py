"""Bag to camchain, timed as a user runs it: ``python -m calib_eval.benchmark.bag_timing [--out DIR]``.

Rendered rigs (:mod:`calib_eval.benchmark.rendered`) are written as ROS1 bags of raw mono8 images,
one topic per camera. Then ``calib-eval calibrate --bag REC --topics ... --models pinhole-equi ...
--select`` runs in a fresh process, as a user would run it: once cold (images read from the bag
and detected) and then warm (``--repeats`` times, detections read from the cache). Reading the
bag alone is timed in-process; detection is the cold run less the warm one and the read. Rows: a
stereo rig at 160 and 480 frames, and a six-camera ring at 160 frames (how it grows with cameras).
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import time
from pathlib import Path

import cv2
import numpy as np

from calib_eval.benchmark.rendered import render_rig_sequence
from calib_eval.benchmark.rigs import paper_config
from cotrain.io.bags import bag_to_sequence, write_image_bag

RUNS = [("FoV220_90", 160), ("FoV220_90", 480), ("FoV220_hex", 160)]
T0 = 1_700_000_000_000_000_000  # header stamps: the rendered sequence's times plus this


def write_rig_bag(seq_dir: Path, frames: int, n_cams: int, bag: Path) -> Path:
    """A ROS1 bag of the first ``frames`` frames of a rendered sequence folder."""
    cams = []
    for c in range(n_cams):
        rows = (seq_dir / f"cam{c}" / "timestamps.csv").read_text().splitlines()[1 : frames + 1]
        cams.append([(T0 + int(r.split(",")[1]), cv2.imread(str(seq_dir / f"cam{c}" / "images" / r.split(",")[2]), 0)) for r in rows])
    if bag.exists():
        bag.unlink()
    return write_image_bag(bag, 1, cams)


def calibrate_cli(bag: Path, n_cams: int, fov: float, out: Path) -> tuple[float, dict]:
    """Wall time of ``calib-eval calibrate --bag`` in a fresh process, and its report.json."""
    cmd = [sys.executable, "-m", "calib_eval.cli", "calibrate", "--bag", str(bag)]
    cmd += ["--topics", *[f"/cam{c}/image_raw" for c in range(n_cams)], "--fov", f"{fov:g}"]
    cmd += ["--models", *["pinhole-equi"] * n_cams, "--select", "--out", str(out)]
    t0 = time.time()
    p = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.time() - t0
    if p.returncode != 0:
        print(p.stdout[-2000:], p.stderr[-2000:], file=sys.stderr)
    report = json.loads((out / "report.json").read_text()) if (out / "report.json").is_file() else {}
    return wall, report


def time_rig(rig_name: str, frames: int, out: Path, repeats: int = 3, seed: int = 7) -> dict:
    rig = paper_config(rig_name)
    n_cams = len(rig.yaws_deg)
    seq_dir = out / f"render_{rig_name}"
    render_rig_sequence(rig, frames, seq_dir, seed=seed)
    bag = write_rig_bag(seq_dir, frames, n_cams, out / f"{rig_name}_{frames}.bag")
    topics = [f"/cam{c}/image_raw" for c in range(n_cams)]
    t0 = time.time()
    bag_to_sequence(bag, topics, out / "read_only", progress=False)
    read_s = time.time() - t0
    shutil.rmtree(out / "read_only")
    calib = out / f"calib_{rig_name}_{frames}"
    shutil.rmtree(calib, ignore_errors=True)
    cold, report = calibrate_cli(bag, n_cams, rig.fov, calib)
    warm = [calibrate_cli(bag, n_cams, rig.fov, calib)[0] for _ in range(repeats)]
    w = float(np.median(warm))
    return {
        "rig": rig_name,
        "cameras": n_cams,
        "frames": frames,
        "images": n_cams * frames,
        "bag_mb": bag.stat().st_size / 1e6,
        "success": bool(report.get("success")),
        "rms_px": report.get("rms_px"),
        "cold_s": cold,
        "warm_s": w,
        "warm_runs_s": warm,
        "read_s": read_s,
        "detect_s": max(0.0, cold - w - read_s),
        "calibrate_s": report.get("runtime_s"),
        "selection": report.get("selection"),
    }


def table(rows: list[dict]) -> str:
    lines = [
        "| rig | cameras | frames | bag (MB) | bag -> camchain, cold (s) | cached detections (s) | read bag (s) | detect (s) "
        "| ms per image (read + detect) | calibrate (s) | result |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        per = 1000 * (r["read_s"] + r["detect_s"]) / r["images"]
        res = "ok, RMS " + ", ".join(f"{v:.2f}" for v in r["rms_px"].values()) + " px" if r["success"] else "failed"
        lines.append(
            f"| {r['rig']} | {r['cameras']} | {r['frames']} | {r['bag_mb']:.0f} | {r['cold_s']:.0f} | {r['warm_s']:.0f} | "
            f"{r['read_s']:.0f} | {r['detect_s']:.0f} | {per:.0f} | {r['calibrate_s']:.0f} | {res} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--out", default="report/bag_timing")
    p.add_argument("--repeats", type=int, default=3, help="warm runs (median)")
    p.add_argument("--runs", nargs="+", default=[f"{r}:{f}" for r, f in RUNS], help="RIG:FRAMES, e.g. FoV220_90:480")
    a = p.parse_args(argv)
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    for spec in a.runs:
        rig_name, frames = spec.split(":")
        rows.append(time_rig(rig_name, int(frames), out, a.repeats))
        print(table(rows[-1:]), flush=True)
        (out / "bag_timing.json").write_text(json.dumps(rows, indent=1))
    text = f"# Bag to camchain\n\n{table(rows)}\n"
    (out / "bag_timing.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    sys.exit(main())
