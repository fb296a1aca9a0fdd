"""An AprilGrid rig end to end: ``python -m calib_eval.benchmark.aprilgrid_rig [--rig FoV220_90] [--frames N] [--glare P] [--out DIR]``.

A stereo rig (the paper's configurations, :func:`calib_eval.benchmark.rigs.paper_config`) looks at
Kalibr's 6 x 6 AprilGrid: the frames are rendered, the tag pass detects them
(:class:`cotrain.detect.detector.Detector`; ``--glare``: a spot of light on the print in
that share of the frames), the selector picks the observations and the
calibrator solves, unchanged: the target comes from the detections. Scored against the ground truth
with the checkerboard's tolerances (:mod:`calib_eval.benchmark.robustness`), and every detected
corner against its ground-truth projection (:func:`corner_errors`); writes
``aprilgrid_rig.md`` / ``.json``, the camchain and report.html in ``out``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np
import torch

from calib_eval.benchmark.rendered import render_rig_sequence
from calib_eval.benchmark.rigs import GroundTruth, paper_config
from calib_eval.benchmark.robustness import TOLERANCES, score
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.camchain import write_outputs
from calib_eval.calibration.report_html import write_report_html
from calib_eval.calibration.selector import SelectorConfig, select
from cotrain.detect.detector import Detector
from cotrain.geometry import cameras, poses
from cotrain.io.detections import detect_files, json_safe
from cotrain.io.sequence import Sequence, load_sequence, write_camera_detections
from cotrain.targets import Target, TargetConfig, make_target


def corner_errors(seq: Sequence, gt: GroundTruth, board: Target) -> np.ndarray:
    """(M,) pixel distance of every detected corner of ``seq`` from where the ground truth
    projects its id (camera ``o.cam``, board pose of view ``o.view``: the frames as
    :func:`calib_eval.benchmark.rendered.render_rig_sequence` writes them); inf where the ground
    truth does not project it (counted as wrong)."""
    P = board.points(torch.float64)
    out = [np.zeros(0)]
    for o in seq.observations:
        T = torch.from_numpy(gt.T_cam_rig[o.cam] @ gt.T_rig_board[o.view])
        q, _ = cameras.project(gt.model[o.cam], poses.transform_points(T, P), torch.from_numpy(gt.params[o.cam]))
        e = np.linalg.norm(np.asarray(o.q) - q.numpy()[o.ids], axis=1)
        out.append(np.where(np.isfinite(e), e, np.inf))
    return np.concatenate(out)


def run(rig_name: str, frames: int, out: Path, seed: int = 11, glare: float = 0.0, detector: Detector | None = None) -> dict:
    """Render, detect (``detector``, default the tag pass as shipped), select, calibrate and score;
    the summary as ``aprilgrid_rig.json`` holds it."""
    out.mkdir(parents=True, exist_ok=True)
    rig = paper_config(rig_name)
    target = TargetConfig(kind="aprilgrid")
    seq_dir = out / "sequence"
    t0 = time.time()
    _, gt = render_rig_sequence(rig, frames, seq_dir, seed=seed, target=target, glare=glare)
    t_render = time.time() - t0
    det = detector or Detector(target=make_target(target))
    for c in range(len(gt.params)):
        write_camera_detections(seq_dir / f"cam{c}", lambda paths: detect_files(paths, det, workers=0))
    t_detect = time.time() - t0 - t_render
    seq = load_sequence(seq_dir)
    err = corner_errors(seq, gt, make_target(target))
    sel = select(seq, SelectorConfig())
    chosen = seq.subset(sel.keep)
    res = calibrate(chosen, CalibConfig(model=rig.model, fov=rig.fov), sel.order)
    write_outputs(res, chosen, out, {"selection": sel.summary()})
    write_report_html(res, chosen, out)
    r = score(res, gt, rig.fov, set())
    summary = {
        "rig": rig_name,
        "frames": frames,
        "glare": glare,
        "target": make_target(target).to_json(),
        "observations": len(seq.observations),
        "corners": int(sum(len(o.ids) for o in seq.observations)),
        "selected": len(sel.keep),
        "corner_err_px": {
            "median": float(np.median(err)),
            "p99": float(np.percentile(err, 99)),
            "over_1px": int((err > 1).sum()),
            "over_3px": int((err > 3).sum()),
        },
        "render_s": t_render,
        "detect_s": t_detect,
        "result": r,
        "rms_px": list(res.rms_px) if res.success else None,
        "tolerances": TOLERANCES,
    }
    (out / "aprilgrid_rig.json").write_text(json.dumps(json_safe(summary), indent=1))
    (out / "aprilgrid_rig.md").write_text(table(summary))
    return summary


def table(s: dict) -> str:
    r = s["result"]
    res = "strict success" if r["strict"] else ("success, not strict" if r["success"] else f"failed: {r['reason']}")
    rms = ", ".join(f"{v:.3f}" for v in s["rms_px"]) if s["rms_px"] else "-"
    t = s["tolerances"]
    e = s["corner_err_px"]
    return "\n".join(
        [
            "# AprilGrid rig: rendered, detected by the tag pass, selected, calibrated",
            "",
            f"{s['rig']}, Kalibr's 6 x 6 AprilGrid, {s['frames']} frames"
            + (f" (a glare on the print in {s['glare']:.0%} of them)" if s.get("glare") else "")
            + f": {s['observations']} observations with "
            f"{s['corners']} corners detected; the selector kept {s['selected']}.",
            f"Against their ground-truth projections: median {e['median']:.3f} px, 99th percentile {e['p99']:.3f} px, "
            f"{e['over_1px']} over 1 px, {e['over_3px']} over 3 px (wrong).",
            "",
            "| result | RMS (px, per camera) | focal (%) | principal point (px) | extrinsics (mm / deg) "
            "| within the checkerboard's tolerances |",
            "|---|---|---|---|---|---|",
            f"| {res} | {rms} | {r['focal_pct']:.4f} | {r['pp_px']:.3f} | {r['ext_mm']:.3f} / {r['ext_deg']:.4f} "
            f"| {'yes' if r['within_tolerances'] else 'no'} |",
            "",
            f"Tolerances: focal {t['focal_pct']} %, principal point {t['pp_px']} px, extrinsics {t['ext_mm']} mm / {t['ext_deg']} deg. "
            f"Render {s['render_s']:.0f} s, detection {s['detect_s']:.0f} s on this machine.",
            "",
        ]
    )


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.aprilgrid_rig", description=__doc__.splitlines()[0])
    p.add_argument("--rig", default="FoV220_90")
    p.add_argument("--frames", type=int, default=120)
    p.add_argument("--glare", type=float, default=0.0, help="share of the frames with a spot of light on the print")
    p.add_argument("--out", default="runs/aprilgrid_rig")
    a = p.parse_args(argv)
    torch.set_num_threads(2)
    np.set_printoptions(precision=4)
    if not 0.0 <= a.glare <= 1.0:
        p.error(f"--glare must lie in [0, 1], not {a.glare}")
    s = run(a.rig, a.frames, Path(a.out), glare=a.glare)
    print(table(s))
    return 0 if s["result"]["strict"] else 1


if __name__ == "__main__":
    sys.exit(main())
