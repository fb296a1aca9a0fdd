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


def run_pipeline(cfg: PipelineConfig, from_scratch: bool = False) -> int:
    t_start = time.time()
    out = Path(cfg.out_dir)
    out.mkdir(parents=True, exist_ok=True)
    status: dict[str, str] = {}
    seconds: dict[str, float] = {}  # run time per stage
    figures: dict[str, object] = {}
    init = "" if from_scratch else cfg.init_checkpoint
    if init == "export/default.pt" and not Path(init).is_file():  # an installed package: the shipped file
        init = str(default_model_path().with_suffix(".pt"))
    if init and not Path(init).is_file():
        raise FileNotFoundError(f"{init}: shipped checkpoint not found (use --from-scratch to train without it)")
    if not Path(cfg.train_config).is_file():
        raise ConfigError(f"{cfg.train_config}: training config not found")

    # 1. Train.
    _stage(f"1/4 train ({cfg.train_steps} steps, {'from scratch' if not init else 'fine-tuning ' + init})")
    t0 = time.time()
    run_dir = out / "train"
    if run_dir.exists():
        shutil.rmtree(run_dir)
    overrides = [f"train.steps={cfg.train_steps}", f"train.out_dir={run_dir}", f"train.init_from={init}", *cfg.train_overrides]
    tcfg = finalize_config(load_config(TrainConfig, cfg.train_config, overrides))
    tr = train(tcfg)
    seconds["train"] = time.time() - t0
    figures["train"] = {"steps": tr["step"], "last_loss": tr["last_loss"], "best_val_recall": tr["best_score"], "seconds": seconds["train"]}
    status["train"] = "ok"

    # 2. Export.
    _stage("2/4 export to ONNX (parity check)")
    t0 = time.time()
    onnx_path = out / "model.onnx"
    ex = export_onnx(run_dir / "best.pt", onnx_path)
    figures["export"] = ex
    status["export"] = f"ok (max corner difference {ex['max_corner_diff_px']:.1e} px)"
    seconds["export"] = time.time() - t0
    print(status["export"])

    # 3. Detection evaluation.
    _stage("3/4 detection evaluation per FoV")
    t0 = time.time()
    ecfg = EvalConfig(fovs=cfg.eval_fovs, per_fov=cfg.eval_per_fov, n_empty=cfg.eval_empty, conditions=[])  # FoV rows only
    ev = evaluate_detection(str(onnx_path), ecfg, out / "detection")
    figures["detection"] = ev["results"]
    learned = ev["results"]["learned"]["per_fov"]
    mean_recall = float(np.mean([r["recall"] for r in learned.values()]))
    status["detection"] = f"learned mean recall {mean_recall:.3f} over FoVs {cfg.eval_fovs}"
    det = Detector(onnx_path)
    ov_dir = out / "overlays"
    ov_dir.mkdir(exist_ok=True)
    for p in sorted((out / "detection" / "images").glob("fov*.png"))[:: max(1, (cfg.eval_per_fov * len(cfg.eval_fovs)) // cfg.overlays)][
        : cfg.overlays
    ]:
        g = load_image(p)
        cv2.imwrite(str(ov_dir / p.name), draw_detection(g, det.detect(g)))
    seconds["detection"] = time.time() - t0

    # 4. Calibration through the exported detector.
    _stage(f"4/4 calibration check: {cfg.calib_rig}, {cfg.calib_frames} rendered frames -> detect -> select -> calibrate")
    t0 = time.time()
    seq_dir = out / "calibration" / "sequence"
    if seq_dir.exists():
        shutil.rmtree(seq_dir)
    rig = paper_config(cfg.calib_rig)
    _, gt = render_rig_sequence(rig, cfg.calib_frames, seq_dir, seed=11)
    for cam_dir in sorted(seq_dir.glob("cam*")):
        paths = sorted((cam_dir / "images").glob("*.png"))
        data = detect_files(paths, det, workers=0)
        for e in data["images"]:
            e["path"] = str(Path(e["path"]).relative_to(seq_dir))
        write_json_atomic(data, cam_dir / "detections.json")
    seq = load_sequence(seq_dir)
    sel = select(seq, SelectorConfig(fov=rig.fov))
    ccfg = CalibConfig(model=cfg.calib_model, fov=rig.fov)
    res = calibrate(seq.subset(sel.keep), ccfg, order=sel.order)
    ev_c = evaluate_result(res, gt, rig.fov)
    pub = publish(res, seq.subset(sel.keep), ccfg, out / "calibration", {"selection": sel.summary(), "against_ground_truth": ev_c})
    figures["calibration"] = ev_c
    if res.success:
        status["calibration"] = (
            f"{'strict success' if ev_c['strict'] else 'success (not strict)'}: extrinsic error "
            f"{ev_c['ext_mm']:.2f} mm / {ev_c['ext_deg']:.3f} deg, intrinsics {ev_c['intr_px']:.2f} px RMS from truth"
        )
    else:
        status["calibration"] = f"failed: {res.reason}"
    status["calibration"] += f"; {pub.trust.verdict.line()} (calibration/report.html)"
    seconds["calibration"] = time.time() - t0
    print(status["calibration"])

    # Summary.
    total = time.time() - t_start
    lines = ["# cotrain pipeline report", "", f"Total time {total / 60:.1f} min.", "", "| stage | result |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in status.items()]
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
    (out / "summary.md").write_text("\n".join(lines))
    (out / "summary.json").write_text(
        json.dumps({"status": status, "seconds": seconds, "figures": figures, "total_s": total}, indent=1, default=str)
    )
    index = write_index(out, status, seconds, ev["results"], cfg.eval_fovs, ev_c, total)
    print(f"\npipeline finished in {total / 60:.1f} min -> {index}")
    return 0
