"""The main job end to end: ``cotrain pipeline [--config configs/pipeline.yaml] [--from-scratch]``.

Stages (each shows progress and fails loudly and early on bad input):
1. train: a short CPU run, fine-tuning the shipped model (or from scratch);
2. export: ONNX with the onnxruntime parity check;
3. detection: per-FoV recall and error against the geometry-based detectors;
4. calibration: a synthetic stereo sequence rendered as images -> detect -> select -> calibrate,
   compared with the ground truth.
Everything lands in a report folder: ``index.html``, the page to read (self-contained:
:mod:`calib_eval.report_index`), a short ``summary.md`` for terminals and ``summary.json``.
"""

from __future__ import annotations

import json
import shutil
import time
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from calib_eval.benchmark.benchmark import evaluate_result
from calib_eval.benchmark.rendered import render_rig_sequence
from calib_eval.benchmark.rigs import paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.publish import publish
from calib_eval.calibration.selector import SelectorConfig, select
from calib_eval.detection.evaluation import EvalConfig, evaluate_detection
from calib_eval.report_index import ground_truth_rows, markdown_table, write_index
from cotrain.config import ConfigError, load_config
from cotrain.detect.detector import Detector, draw_detection
from cotrain.detect.images import load_image
from cotrain.detect.onnx_model import default_model_path
from cotrain.io.detections import detect_files, write_json_atomic
from cotrain.io.sequence import load_sequence
from cotrain.model.train import TrainConfig, finalize_config, train
from export.onnx_export import export_onnx


@dataclass
class PipelineConfig:
    out_dir: str = "report"  # the report folder
    train_config: str = "configs/default.yaml"  # training recipe the short run starts from
    train_steps: int = 120  # steps of the short run
    train_overrides: list[str] = field(
        default_factory=lambda: [
            "train.val_size=32",
            "train.val_every=60",
            "train.warmup_steps=10",
            "train.lr=0.0003",
            "train.image_every=60",
            "train.curriculum_steps=0",
        ]
    )  # key=value
    init_checkpoint: str = "export/default.pt"  # shipped weights to fine-tune ("" or --from-scratch: random init)
    eval_fovs: list[int] = field(default_factory=lambda: [180, 200, 220, 240])  # detection evaluation FoVs
    eval_per_fov: int = 8  # images per FoV
    eval_empty: int = 4  # images without a target
    calib_rig: str = "FoV200_90"  # synthetic stereo rig rendered for the calibration check
    calib_frames: int = 48  # frames of that sequence
    calib_model: str = "kb4"  # camera model the calibrator fits
    overlays: int = 6  # detection overlays written to the report


def _stage(name: str) -> None:
    print(f"\n=== {name} ===", flush=True)


@dataclass
class _Run:
    """What the stages record, by stage name: the result line, the run time and the figures."""

    out: Path  # the report folder
    status: dict[str, str] = field(default_factory=dict)
    seconds: dict[str, float] = field(default_factory=dict)
    figures: dict[str, object] = field(default_factory=dict)


def _initial_checkpoint(cfg: PipelineConfig, from_scratch: bool) -> str:
    """The checkpoint the short run fine-tunes ("" from scratch); a missing one is an error."""
    init = "" if from_scratch else cfg.init_checkpoint
    if init == "export/default.pt" and not Path(init).is_file():  # an installed package: the shipped file
        init = str(default_model_path().with_suffix(".pt"))
    if init and not Path(init).is_file():
        raise FileNotFoundError(f"{init}: shipped checkpoint not found (use --from-scratch to train without it)")
    if not Path(cfg.train_config).is_file():
        raise ConfigError(f"{cfg.train_config}: training config not found")
    return init


def _train_stage(cfg: PipelineConfig, run: _Run, init: str) -> Path:
    """1. The short training run; returns its folder (best.pt inside)."""
    _stage(f"1/4 train ({cfg.train_steps} steps, {'from scratch' if not init else 'fine-tuning ' + init})")
    t0 = time.time()
    run_dir = run.out / "train"
    if run_dir.exists():
        shutil.rmtree(run_dir)
    overrides = [f"train.steps={cfg.train_steps}", f"train.out_dir={run_dir}", f"train.init_from={init}", *cfg.train_overrides]
    tr = train(finalize_config(load_config(TrainConfig, cfg.train_config, overrides)))
    run.seconds["train"] = time.time() - t0
    run.figures["train"] = {
        "steps": tr["step"],
        "last_loss": tr["last_loss"],
        "best_val_recall": tr["best_score"],
        "seconds": run.seconds["train"],
    }
    run.status["train"] = "ok"
    return run_dir


def _export_stage(run: _Run, run_dir: Path) -> Path:
    """2. ONNX export with the parity check; returns the graph's path."""
    _stage("2/4 export to ONNX (parity check)")
    t0 = time.time()
    onnx_path = run.out / "model.onnx"
    ex = export_onnx(run_dir / "best.pt", onnx_path)
    run.figures["export"] = ex
    run.status["export"] = f"ok (max corner difference {ex['max_corner_diff_px']:.1e} px)"
    run.seconds["export"] = time.time() - t0
    print(run.status["export"])
    return onnx_path


def _detection_stage(cfg: PipelineConfig, run: _Run, onnx_path: Path) -> tuple[dict, Detector]:
    """3. Per-FoV detection evaluation and a few overlays; returns the evaluation and the detector."""
    _stage("3/4 detection evaluation per FoV")
    t0 = time.time()
    ecfg = EvalConfig(fovs=cfg.eval_fovs, per_fov=cfg.eval_per_fov, n_empty=cfg.eval_empty, conditions=[])  # FoV rows only
    ev = evaluate_detection(str(onnx_path), ecfg, run.out / "detection")
    run.figures["detection"] = ev["results"]
    learned = ev["results"]["learned"]["per_fov"]
    mean_recall = float(np.mean([r["recall"] for r in learned.values()]))
    run.status["detection"] = f"learned mean recall {mean_recall:.3f} over FoVs {cfg.eval_fovs}"
    det = Detector(onnx_path)
    ov_dir = run.out / "overlays"
    ov_dir.mkdir(exist_ok=True)
    every = max(1, (cfg.eval_per_fov * len(cfg.eval_fovs)) // cfg.overlays)
    for p in sorted((run.out / "detection" / "images").glob("fov*.png"))[::every][: cfg.overlays]:
        g = load_image(p)
        cv2.imwrite(str(ov_dir / p.name), draw_detection(g, det.detect(g)))
    run.seconds["detection"] = time.time() - t0
    return ev, det


def _calibration_stage(cfg: PipelineConfig, run: _Run, det: Detector) -> dict:
    """4. A rendered rig through the exported detector, the selector and the calibrator, against
    its ground truth; returns those figures."""
    _stage(f"4/4 calibration check: {cfg.calib_rig}, {cfg.calib_frames} rendered frames -> detect -> select -> calibrate")
    t0 = time.time()
    seq_dir = run.out / "calibration" / "sequence"
    if seq_dir.exists():
        shutil.rmtree(seq_dir)
    rig = paper_config(cfg.calib_rig)
    _, gt = render_rig_sequence(rig, cfg.calib_frames, seq_dir, seed=11)
    for cam_dir in sorted(seq_dir.glob("cam*")):
        data = detect_files(sorted((cam_dir / "images").glob("*.png")), det, workers=0)
        for e in data["images"]:
            e["path"] = str(Path(e["path"]).relative_to(seq_dir))
        write_json_atomic(data, cam_dir / "detections.json")
    seq = load_sequence(seq_dir)
    sel = select(seq, SelectorConfig(fov=rig.fov))
    ccfg = CalibConfig(model=cfg.calib_model, fov=rig.fov)
    res = calibrate(seq.subset(sel.keep), ccfg, order=sel.order)
    ev_c = evaluate_result(res, gt, rig.fov)
    pub = publish(res, seq.subset(sel.keep), ccfg, run.out / "calibration", {"selection": sel.summary(), "against_ground_truth": ev_c})
    run.figures["calibration"] = ev_c
    if res.success:
        run.status["calibration"] = (
            f"{'strict success' if ev_c['strict'] else 'success (not strict)'}: extrinsic error "
            f"{ev_c['ext_mm']:.2f} mm / {ev_c['ext_deg']:.3f} deg, intrinsics {ev_c['intr_px']:.2f} px RMS from truth"
        )
    else:
        run.status["calibration"] = f"failed: {res.reason}"
    run.status["calibration"] += f"; {pub.trust.verdict.line()} (calibration/report.html)"
    run.seconds["calibration"] = time.time() - t0
    print(run.status["calibration"])
    return ev_c


def _write_summary(run: _Run, ev: dict, ev_c: dict, total: float) -> None:
    """summary.md (for terminals) and summary.json."""
    lines = ["# cotrain pipeline report", "", f"Total time {total / 60:.1f} min.", "", "| stage | result |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in run.status.items()]
    lines += [
        "",
        "## Detection per FoV",
        "",
        ev["table"],
        "",
        "![recall](detection/recall_vs_radius.png)",
        "![errors](detection/error_distribution.png)",
        "",
        "## Calibration against ground truth",
        "",
        markdown_table(["figure", "value"], ground_truth_rows(ev_c)),
        "",
        "The whole report, plots included: `index.html`. Overlays of detections: `overlays/`. "
        "Training logs: `tensorboard --logdir train/tb`.",
        "",
    ]
    (run.out / "summary.md").write_text("\n".join(lines))
    summary = {"status": run.status, "seconds": run.seconds, "figures": run.figures, "total_s": total}
    (run.out / "summary.json").write_text(json.dumps(summary, indent=1, default=str))


def run_pipeline(cfg: PipelineConfig, from_scratch: bool = False) -> int:
    """The four stages in turn; the report folder gets summary.md, summary.json and index.html."""
    t_start = time.time()
    run = _Run(Path(cfg.out_dir))
    run.out.mkdir(parents=True, exist_ok=True)
    init = _initial_checkpoint(cfg, from_scratch)
    run_dir = _train_stage(cfg, run, init)
    onnx_path = _export_stage(run, run_dir)
    ev, det = _detection_stage(cfg, run, onnx_path)
    ev_c = _calibration_stage(cfg, run, det)
    total = time.time() - t_start
    _write_summary(run, ev, ev_c, total)
    index = write_index(run.out, run.status, run.seconds, ev["results"], cfg.eval_fovs, ev_c, total)
    print(f"\npipeline finished in {total / 60:.1f} min -> {index}")
    return 0
