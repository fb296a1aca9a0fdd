"""The ``calib-eval`` command: synthetic sequences, frame selection, calibration, detection
evaluation, the synthetic benchmark and its failure analysis, OpenCV sequences from images."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

from calib_eval.detection import DEFAULT_DETECTORS, DETECTORS
from calib_eval.detection.conditions import CONDITIONS
from cotrain.geometry import MODELS, model_from_name
from cotrain.geometry.cameras import KALIBR_NAMES
from cotrain.targets import Target, load_target, target_from_flags


def _target(path: str | None) -> Target | None:
    """The target of a ``--target`` file (our config section, a Kalibr or a BoofCV target yaml), if given."""
    return load_target(path) if path else None


def cmd_synth(a: argparse.Namespace) -> int:
    from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
    from cotrain.io.sequence import write_sequence

    rig = paper_config(a.config)
    rig.model = a.model
    offsets = tuple(ms / 1000 for ms in a.time_offset_ms or ())
    spec = SynthSpec(
        n_frames=a.frames,
        noise_px=a.noise,
        outlier_rate=a.outliers,
        motion="continuous" if a.continuous or offsets else "random",
        time_offsets_s=offsets,
        bend_m=a.bend_mm / 1000,
    )
    seq, gt = make_sequence(rig, spec, seed=a.seed)
    root = write_sequence(seq, a.out)
    (Path(a.out) / "ground_truth.json").write_text(
        json.dumps(
            {
                "model": gt.model,
                "params": [p.tolist() for p in gt.params],
                "T_cam_rig": gt.T_cam_rig.tolist(),
                "time_offsets_s": gt.time_offsets_s,
                "board_warp_m": list(gt.warp_m),
            },
            indent=1,
        )
    )
    print(f"wrote {root} ({len(seq.cameras)} cameras, {seq.n_views} frames, {len(seq.observations)} observations)")
    return 0


def _resolve_fov(a: argparse.Namespace, seq, models: list[str]) -> None:
    """``a.fov`` as given, or estimated from the sequence (and said so) where it is not."""
    if a.fov is not None:
        return
    from calib_eval.calibration.fov import estimate_fov

    est = estimate_fov(seq, models)
    a.fov = round(est.fov_deg, 1)
    print(est.line([c.name for c in seq.cameras]), flush=True)


def _selector_cfg(a: argparse.Namespace):
    from calib_eval.calibration.selector import SelectorConfig

    return SelectorConfig(
        fov=a.fov,
        iso_gate=a.iso_gate,
        drs_numerator=a.drs_numerator,
        min_corners=a.min_corners,
        max_anchors=a.max_anchors,
        max_covisible=a.max_covisible,
        max_monofill=a.max_monofill,
    )


def _sequence(a: argparse.Namespace, cache: Path | None):
    """The sequence of ``coverage`` / ``select`` / ``calibrate``: the folder given, or one made
    from ``--bag`` or ``--images`` (our detections cached in ``cache``, default beside the input)."""
    from cotrain.io.sequence import load_sequence

    if sum(x is not None for x in (a.seq, a.bag, a.images)) != 1:
        raise ValueError(
            "give a sequence folder, --images DIR0 DIR1 ... (one folder per camera), or --bag REC --topics T0 T1 ... (one of them)"
        )
    if a.topics and a.bag is None:
        raise ValueError("--topics goes with --bag")
    if getattr(a, "fov", None) is not None and not 30 <= a.fov <= 360:  # checked before anything is detected
        raise ValueError(f"--fov {a.fov:g}: give the lens's rough field of view in degrees (30-360), or leave it out to estimate it")
    if a.images is not None and a.every:
        raise ValueError("--every goes with --bag; with --images, keep the images you want in the folders")
    if a.seq is not None:
        a.sequence_folder = a.seq
        return load_sequence(a.seq, a.tolerance_ms, target=_target(a.target))
    from cotrain.detect.detector import make_detector
    from cotrain.io.folders import check_sequence_folder

    target = _target(a.target)
    det = make_detector(target, a.detector)
    if a.images is not None:
        from cotrain.io.folders import sequence_from_folders

        folder = check_sequence_folder(cache or Path(str(a.images[0]).rstrip("/") + ".sequence"), "--cache")
        folder, read = sequence_from_folders(a.images, folder, det, workers=0)
        a.sequence_folder = folder
        counts = ", ".join(f"{d} {n} images" for d, n in zip(a.images, read["images"]))
        how = "cached detections" if read["cached"] else "detected"
        print(f"{counts} (paired by {read['pairing']}; {how}) -> {folder}")
        return load_sequence(folder, a.tolerance_ms, target=target)
    from cotrain.io.bags import sequence_from_bag

    if not a.topics:
        raise ValueError("--bag needs --topics (one image topic per camera)")
    if not 0 <= a.every < float("inf"):
        raise ValueError("--every must be 0 (every image) or a positive number of seconds")
    folder = check_sequence_folder(cache or Path(str(a.bag).rstrip("/") + ".sequence"), "--cache")
    folder, read = sequence_from_bag(a.bag, a.topics, folder, det, interval_s=a.every, workers=0)
    a.sequence_folder = folder
    skipped = sum(read["skipped"])
    how = "cached detections" if read["cached"] else "detected"
    counts = ", ".join(f"{t} {n} images" for t, n in zip(a.topics, read["images"]))
    thinned = f"; {sum(read.get('thinned', []))} left out by --every" if a.every else ""
    print(f"{a.bag}: {counts} ({how}; {skipped} undecodable skipped{thinned}) -> {folder}")
    return load_sequence(folder, a.tolerance_ms, target=target)


def cmd_coverage(a: argparse.Namespace) -> int:
    from calib_eval.calibration.coverage import coverage

    seq = _sequence(a, Path(a.cache) if a.cache else None)
    cov = coverage(seq)
    for cc in cov.cameras:
        print(f"{cc.name}: {cc.views} views, {cc.corners} corners, out to {cc.max_radius:.2f} of the image radius")
    for (ca, cb), n in cov.shared_views.items():
        print(f"{seq.cameras[ca].name} + {seq.cameras[cb].name}: {n} shared views")
    print("\n".join(cov.advice) if cov.advice else "coverage is complete: every camera seen to its rim all round, every camera linked")
    return 0


def cmd_select(a: argparse.Namespace) -> int:
    from calib_eval.calibration.selector import select

    seq = _sequence(a, Path(a.cache) if a.cache else None)
    _resolve_fov(a, seq, [model_from_name("kb4")] * len(seq.cameras))
    sel = select(seq, _selector_cfg(a))
    rows = [
        {
            "camera": seq.cameras[s.cam].name,
            "view": s.view,
            "frame": s.frame,
            "stage": s.stage,
            "order": s.order,
            "n_corners": s.n_corners,
            "s_iso": round(s.s_iso, 4),
            "s_drs": round(s.s_drs, 4),
            "reason": s.reason,
        }
        for s in sorted(sel.scores, key=lambda s: (s.cam, s.order if s.order >= 0 else 10**9, s.view))
    ]
    out = Path(a.out) if a.out else Path(a.sequence_folder) / "selection.json"
    out.write_text(json.dumps({"summary": sel.summary(), "frames": rows}, indent=1))
    print(f"selected {len(sel.keep)} of {len(sel.scores)} observations: {sel.summary()} -> {out}")
    return 0


def time_offset_option(values: list[str] | None) -> tuple[str, dict[int, float]]:
    """``--time-offset``: ``auto``, ``estimate`` or ``off``, or ``camN=SECONDS ...`` set by hand."""
    if not values:
        return "estimate", {}
    if len(values) == 1 and values[0] in ("auto", "estimate", "off"):
        return values[0], {}
    fixed = {}
    for v in values:
        name, _, sec = v.partition("=")
        try:
            cam, seconds = int(name.removeprefix("cam")), float(sec)
        except ValueError:
            raise ValueError(f"--time-offset {v}: give auto, estimate, off, or camN=SECONDS (e.g. cam1=0.015)") from None
        if cam < 1 or not name.startswith("cam"):
            raise ValueError(f"--time-offset {v}: offsets are to cam0, so name cam1, cam2, ...")
        fixed[cam] = seconds
    return "off", fixed


def _models_count(named: int, cameras: int) -> str:
    return (
        f"--models names {named} camera model{'s' if named != 1 else ''} for {cameras} cameras: give one per camera, cam0 first "
        f"(e.g. --models {' '.join(['pinhole-equi'] * cameras)}), or --model M for all of them"
    )


def cmd_calibrate(a: argparse.Namespace) -> int:
    from calib_eval.calibration.calibrator import CalibConfig, calibrate
    from calib_eval.calibration.publish import publish
    from calib_eval.calibration.selector import select
    from calib_eval.calibration.trust import TrustConfig

    t0 = time.time()
    if Path(a.out).exists() and not Path(a.out).is_dir():
        raise ValueError(f"--out {a.out}: an existing file; --out names the folder for camchain.yaml, report.json and report.html")
    if a.model and a.models:
        raise ValueError("give --model (one for every camera) or --models (one per camera), not both")
    names = a.models or [a.model or "kb4"]
    models = [model_from_name(n) for n in names]  # a one-line error for a model we do not support
    timing, fixed = time_offset_option(a.time_offset)
    given = len(a.images) if a.images else len(a.topics) if a.bag and a.topics else None
    if a.models and given is not None and len(models) != given:
        raise ValueError(_models_count(len(models), given))
    seq = _sequence(a, Path(a.cache) if a.cache else Path(a.out) / "sequence")
    if a.models and len(models) != len(seq.cameras):
        raise ValueError(_models_count(len(models), len(seq.cameras)))
    if any(c >= len(seq.cameras) for c in fixed):
        raise ValueError(f"--time-offset names a camera the sequence does not have ({len(seq.cameras)} cameras)")
    if fixed and seq.timestamps_ns is None:
        raise ValueError("--time-offset camN=SECONDS needs the views' timestamps; this sequence has none")
    _resolve_fov(a, seq, models if a.models else models * len(seq.cameras))
    order, extra, anchors = None, {}, None
    if a.select:
        sel = select(seq, _selector_cfg(a))
        seq = seq.subset(sel.keep)
        order = sel.order
        extra["selection"] = sel.summary()
        anchors = {c: [s.view for s in sel.scores if s.cam == c and s.stage == "anchor"] for c in range(len(seq.cameras))}
    cfg = CalibConfig(
        model=models[0],
        models=models if a.models else [],
        fov=a.fov,
        no_init=a.no_init,
        flat_board=a.flat_board,
        time_offset=timing,
        time_offsets_s=fixed,
    )
    res = calibrate(seq, cfg, order)
    print(f"calibrated in {time.time() - t0:.1f} s; checking how far to trust it (uncertainty, cross-validation) ...", flush=True)
    out = publish(
        res,
        seq,
        cfg,
        a.out,
        {**extra, "total_runtime_s": time.time() - t0},
        anchors,
        order,
        TrustConfig(max_projection_sigma_px=a.max_projection_sigma),
    )
    if res.success:
        rms = ", ".join(f"{seq.cameras[c].name} {r:.3f}" for c, r in enumerate(res.rms_px))
        print(f"calibration succeeded in {time.time() - t0:.1f} s (RMS px: {rms}) -> {out.chain}, {out.report}, {out.page}")
        print(out.trust.verdict.line())
        return 0
    print(f"calibration failed: {res.reason} (see {out.report})", file=sys.stderr)
    print(out.trust.verdict.line())
    return 1


def cmd_compare(a: argparse.Namespace) -> int:
    from calib_eval.calibration.calibrator import CalibConfig
    from calib_eval.calibration.compare import compare, write_comparison
    from calib_eval.calibration.mrcal_peer import MrcalConfig
    from calib_eval.calibration.selector import select

    model = model_from_name(a.model)
    out = Path(a.out)
    seq = _sequence(a, Path(a.cache) if a.cache else out / "sequence")
    _resolve_fov(a, seq, [model] * len(seq.cameras))
    order = None
    if not a.all_frames:
        sel = select(seq, _selector_cfg(a))
        seq, order = seq.subset(sel.keep), sel.order
    print(f"calibrating {len(seq.observations)} observations with ours ({model}) and with mrcal ...", flush=True)
    cmp = compare(seq, a.fov, CalibConfig(model=model, fov=a.fov), order, MrcalConfig(lensmodel=a.mrcal_lensmodel), out / "mrcal")
    md, js = write_comparison(cmp, out)
    print(cmp.table())
    print(f"-> {md}, {js}; mrcal's corners file, log and models in {out / 'mrcal'}")
    return 0 if cmp.ours.success else 1


def cmd_detection(a: argparse.Namespace) -> int:
    from calib_eval.detection.evaluation import EvalConfig, evaluate_detection, parse_size

    if a.per_fov < 1:
        raise ValueError("--per-fov must be at least 1")
    if a.model and not Path(a.model).is_file():
        raise FileNotFoundError(f"{a.model}: model not found")
    w, h = parse_size(a.size)
    if a.per_condition < 0:
        raise ValueError("--per-condition must be 0 (no condition rows) or more")
    conditions = [] if a.per_condition == 0 else a.conditions
    cfg = EvalConfig(
        fovs=a.fov, per_fov=a.per_fov, n_empty=a.empty, seed=a.seed, width=w, height=h, conditions=conditions, per_condition=a.per_condition
    )
    evaluate_detection(a.model, cfg, Path(a.out), detectors=a.detectors)
    return 0


def cmd_benchmark(a: argparse.Namespace) -> int:
    from calib_eval.benchmark.benchmark import ALL_CONFIGS, combine, merge, run_benchmark

    configs = ALL_CONFIGS if a.configs == ["all"] else a.configs
    if a.trials < 1:
        raise ValueError("--trials must be at least 1")
    if a.merge_only:
        merge(Path(a.out), a.merge_only, a.trials, a.variants, a.model)
        return 0
    if a.combine:
        missing = [d for d in a.combine if not (Path(d) / "trials.json").is_file()]
        if missing:
            raise FileNotFoundError(f"{missing[0]}: no trials.json (a finished benchmark run's folder)")
        combine([Path(d) for d in a.combine], Path(a.out), a.trials, a.model)
        return 0
    opts = dict(workers=a.workers, frames=a.frames, variants=a.variants, model=a.model, mrcal_timeout_s=a.mrcal_timeout)
    run_benchmark(configs, a.trials, Path(a.out), **opts)
    return 0


def cmd_robustness(a: argparse.Namespace) -> int:
    from calib_eval.benchmark.robustness import RobustnessConfig, run_robustness

    if a.frames < 10:
        raise ValueError("--frames must be at least 10")
    cfg = RobustnessConfig(rig=a.config, frames=a.frames, misidentified=a.misidentified, gross=a.gross, seed=a.seed, detector=a.detector)
    s = run_robustness(cfg, Path(a.out))
    return 0 if s["rows"]["corrupted"]["within_tolerances"] else 1


def cmd_analysis(a: argparse.Namespace) -> int:
    from calib_eval.benchmark.analysis import run_analysis

    bdir = Path(a.benchmark) if a.benchmark else None
    if bdir is not None and not (bdir / "trials.json").is_file():
        raise FileNotFoundError(f"{bdir}: no trials.json (run calib-eval benchmark --out {bdir} first)")
    run_analysis(bdir, Path(a.out), fov=a.fov)
    return 0


def cmd_opencv_detect(a: argparse.Namespace) -> int:
    from calib_eval.detection.opencv_baseline import opencv_detect
    from cotrain.detect.images import expand_inputs
    from cotrain.io.sequence import images_to_sequence

    if not Path(a.images).is_dir():
        raise NotADirectoryError(f"{a.images}: not a folder of images")
    size = 1.0 if a.square_size is None and a.squares_x is not None else a.square_size  # any unit: it only scales the poses
    tgt = target_from_flags(a.target, a.squares_x, a.squares_y, size)
    if tgt is None:
        raise ValueError("name the board: --target TARGET.yaml, or --squares-x X --squares-y Y")
    if a.model and not a.learned:
        raise ValueError("--model goes with --learned")
    if a.sb and a.learned:
        raise ValueError("--sb chooses an OpenCV detector; it does not go with --learned")
    paths = expand_inputs([a.images])
    if not paths:
        raise FileNotFoundError(f"{a.images}: no images")
    if a.learned:
        from cotrain.detect.detector import make_detector
        from cotrain.io.detections import detect_files

        det = make_detector(tgt, a.model)
        detect = lambda files: detect_files(files, det, workers=0)  # noqa: E731
    else:
        detect = lambda files: opencv_detect(files, tgt, "sb" if a.sb else "classic")  # noqa: E731
    seq = images_to_sequence(paths, Path(a.out), detect)
    print(f"wrote {seq}/cam0 (images, timestamps.csv, detections.json with the target); calibrate it with calib-eval calibrate {seq}")
    return 0


def source_args(s: argparse.ArgumentParser) -> None:
    """Where the observations come from: a sequence folder, or a bag and its topics."""
    s.add_argument("seq", nargs="?", help="sequence folder (cam0/, cam1/, ... with timestamps.csv and detections.json)")
    s.add_argument("--bag", help="instead of SEQ: a ROS1 .bag or ROS2 bag folder (read with rosbags, no ROS install)")
    s.add_argument(
        "--images",
        nargs="+",
        metavar="DIR",
        help="instead of SEQ: one image folder per camera, cam0 first; images pair by identical names, by order where names differ, "
        "by time where names are nanosecond stamps",
    )
    s.add_argument("--topics", nargs="+", metavar="TOPIC", help="with --bag: one image topic per camera, cam0 first")
    s.add_argument(
        "--every",
        type=float,
        default=0.0,
        metavar="SECONDS",
        help="with --bag: at most one image per camera per this many seconds (the same time slots for every camera)",
    )
    s.add_argument(
        "--cache",
        help="with --bag or --images: the sequence folder for the detections (default: OUT/sequence, or BAG.sequence, DIR0.sequence)",
    )
    s.add_argument("--detector", help="with --bag or --images: ONNX model for the corners (default: the shipped model)")
    s.add_argument(
        "--target", help="target file (our target config, a Kalibr or a BoofCV target yaml); only where the detections name none"
    )
    s.add_argument("--tolerance-ms", type=float, default=10.0, help="time matching tolerance between cameras")


def seq_args(s: argparse.ArgumentParser) -> None:
    source_args(s)
    s.add_argument(
        "--fov",
        type=float,
        help="rough FoV in degrees across the image circle (lens data sheet; default: estimated from the views, and said so)",
    )
    s.add_argument("--iso-gate", type=float, default=0.3)
    s.add_argument("--drs-numerator", type=float, default=110.0, help="s_drs gate = this / FoV")
    s.add_argument("--min-corners", type=int, default=8)
    s.add_argument("--max-anchors", type=int, default=0)
    s.add_argument("--max-covisible", type=int, default=0)
    s.add_argument("--max-monofill", type=int, default=0)


def _add_calibration_commands(sub) -> None:
    """coverage, select, calibrate and compare: the commands that read a recording."""
    s = sub.add_parser("coverage", help="what a recording shows of each image circle, and what to capture next")
    source_args(s)
    s.set_defaults(func=cmd_coverage)

    s = sub.add_parser("select", help="score and select frames (anchors, co-visible, mono-fill)")
    seq_args(s)
    s.add_argument("--out", help="selection JSON (default: in the sequence folder, SEQ/selection.json)")
    s.set_defaults(func=cmd_select)

    s = sub.add_parser("calibrate", help="calibrate a multi-fisheye rig; writes camchain.yaml and report.json")
    seq_args(s)
    names = ", ".join([*MODELS, *KALIBR_NAMES])
    s.add_argument("--model", help=f"camera model of every camera (default kb4): {names}")
    s.add_argument(
        "--models", nargs="+", metavar="MODEL", help="one camera model per camera, Kalibr's names accepted (e.g. ds-none pinhole-equi)"
    )
    s.add_argument("--select", action="store_true", help="use the selector's frames (anchors first)")
    s.add_argument("--no-init", action="store_true", help="skip intrinsic initialisation (BA-only ablation)")
    s.add_argument("--flat-board", action="store_true", help="take the board as flat (default: estimate its warp)")
    s.add_argument(
        "--time-offset",
        nargs="+",
        metavar="OFFSET",
        help="auto: estimate each camera's time offset to cam0 and calibrate with it; off; camN=SECONDS ...: set by hand "
        "(default: estimate and report, calibrate without)",
    )
    s.add_argument(
        "--max-projection-sigma",
        type=float,
        metavar="PX",
        help="the stated use: projection uncertainty (95th percentile, px) above which the verdict says few_views "
        "(default: half the measured corner noise)",
    )
    s.add_argument("--out", required=True)
    s.set_defaults(func=cmd_calibrate)

    s = sub.add_parser("compare", help="ours and mrcal (mrcal-calibrate-cameras, where installed) on the same detections")
    seq_args(s)
    s.add_argument("--model", default="kb4", help=f"our camera model for every camera (default kb4): {names}")
    s.add_argument("--mrcal-lensmodel", default="", help="mrcal's lens model (default: splined stereographic over --fov)")
    s.add_argument("--all-frames", action="store_true", help="every frame for both (default: the selector's frames for both)")
    s.add_argument("--out", required=True, help="folder for compare.md, compare.json and mrcal's files")
    s.set_defaults(func=cmd_compare)


def _add_evaluation_commands(sub) -> None:
    """detection, benchmark, robustness, opencv-detect and analysis."""
    s = sub.add_parser("detection", help="per-FoV detection evaluation against geometry-based detectors")
    s.add_argument("--model", help="ONNX model (default: the shipped model)")
    s.add_argument("--fov", type=int, nargs="+", default=[180, 200, 220, 240])
    s.add_argument("--per-fov", type=int, default=50)
    s.add_argument("--empty", type=int, default=20, help="images without a target")
    s.add_argument("--per-condition", type=int, default=24, help="images per hard-condition row (0: none)")
    s.add_argument(
        "--conditions", nargs="+", default=list(CONDITIONS), choices=list(CONDITIONS), metavar="C", help="hard-condition rows (default all)"
    )
    s.add_argument("--seed", type=int, default=2026, help="benchmark seed (2026: the evaluation set; tune on others)")
    s.add_argument("--size", default="1280x720", help="image size WIDTHxHEIGHT (other rigs: 1024x1024, 1920x1080, ...)")
    s.add_argument(
        "--detectors",
        nargs="+",
        default=DEFAULT_DETECTORS,
        choices=DETECTORS,
        help="detectors to run (learned: the default detector, grid pass; learned_slots: the network's per-slot "
        "corners); others whose predictions on this set are saved in --out stay in the table",
    )
    s.add_argument("--out", default="report/detection")
    s.set_defaults(func=cmd_detection)

    s = sub.add_parser("benchmark", help="synthetic calibration benchmark: all frames, selector, random subset, BA-only")
    s.add_argument(
        "--configs",
        nargs="+",
        default=["FoV180_90", "FoV220_0", "FoV220_90", "FoV240_60"],
        help="FoV<deg>_<yaw> / FoV<deg>_hex names, or 'all' (16 paper configurations + the hex rig)",
    )
    s.add_argument("--trials", type=int, default=2, help="sequences per configuration (paper: 100)")
    s.add_argument("--frames", type=int, default=480)
    s.add_argument("--model", default="ds", choices=list(MODELS), help="camera model the calibrator fits")
    s.add_argument(
        "--variants",
        nargs="+",
        default=["all", "selector", "random", "ba_only"],
        choices=["all", "selector", "random", "ba_only", "mrcal"],
        help="mrcal: the peer mrcal-calibrate-cameras on the selector's frames, where installed",
    )
    s.add_argument("--workers", type=int, default=0, help="parallel processes (0 = one per CPU core)")
    s.add_argument("--merge-only", type=int, default=0, metavar="WORLD", help="only merge the shards of a WORLD-rank run")
    s.add_argument("--combine", nargs="+", metavar="DIR", help="one table from finished runs with other --variants")
    s.add_argument("--mrcal-timeout", type=float, default=120.0, help="seconds before mrcal's tool is stopped (counted as its failure)")
    s.add_argument("--out", default="report/benchmark")
    s.set_defaults(func=cmd_benchmark)

    s = sub.add_parser("robustness", help="rendered rig with misidentified boards and gross corners: clean, corrupted, view test off")
    s.add_argument("--config", default="FoV220_90", help="FoV<deg>_<yaw> rig")
    s.add_argument("--frames", type=int, default=160)
    s.add_argument("--misidentified", type=float, default=0.05, help="share of views with a misidentified board")
    s.add_argument("--gross", type=float, default=0.05, help="share of corners made gross outliers")
    s.add_argument("--seed", type=int, default=7)
    s.add_argument("--detector", help="ONNX model (default: the shipped model)")
    s.add_argument("--out", default="report/robustness")
    s.set_defaults(func=cmd_robustness)

    s = sub.add_parser("opencv-detect", help="one-camera sequence folder from images, with OpenCV's (--learned: our) chessboard detections")
    s.add_argument("images", help="folder of images")
    s.add_argument("--target", help="target file: our target config, a Kalibr or a BoofCV target yaml")
    s.add_argument("--squares-x", type=int, help="or: squares along the board's x axis")
    s.add_argument("--squares-y", type=int, help="... and along its y axis")
    s.add_argument("--square-size", type=float, help="with --squares-x/-y: metres (default 1: any unit, it only scales the poses)")
    s.add_argument("--sb", action="store_true", help="findChessboardCornersSB instead of findChessboardCorners + cornerSubPix")
    s.add_argument("--learned", action="store_true", help="our detector (network + grid pass) instead of OpenCV's")
    s.add_argument("--model", help="with --learned: ONNX model (default: the shipped model)")
    s.add_argument("--out", required=True, help="sequence folder to write")
    s.set_defaults(func=cmd_opencv_detect)

    s = sub.add_parser("analysis", help="failure analysis: gamma trajectories, coupling index, distribution metrics")
    s.add_argument("--benchmark", help="a benchmark output folder (for gamma and distribution metrics)")
    s.add_argument("--fov", type=float, default=220.0, help="FoV of the coupling-index analysis")
    s.add_argument("--out", default="report/analysis")
    s.set_defaults(func=cmd_analysis)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="calib-eval", description="Fisheye calibration: selection, calibration, evaluation.")
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("synth", help="write a synthetic rig sequence (detections + ground truth) in the folder layout")
    s.add_argument("--config", default="FoV220_90", help="FoV<deg>_<yaw> or FoV<deg>_hex")
    s.add_argument("--model", default="kb4", choices=list(MODELS))
    s.add_argument("--frames", type=int, default=480)
    s.add_argument("--noise", type=float, default=0.3, help="detector noise, px")
    s.add_argument("--outliers", type=float, default=0.0, help="fraction of gross outliers")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("--continuous", action="store_true", help="a board moving smoothly at 20 Hz (default: independent random views)")
    s.add_argument(
        "--time-offset-ms",
        type=float,
        nargs="+",
        metavar="MS",
        help="per camera, cam0 first: exposed this long after the stamp (continuous)",
    )
    s.add_argument("--bend-mm", type=float, default=0.0, help="the board bent as a cylinder: offset at its centre (mm)")
    s.add_argument("--out", required=True)
    s.set_defaults(func=cmd_synth)

    _add_calibration_commands(sub)
    _add_evaluation_commands(sub)
    return p


def run(argv: list[str] | None = None) -> int:
    from cotrain.cli import dispatch

    return dispatch("calib-eval", build_parser().parse_args(argv))


def main() -> None:
    sys.exit(run())


if __name__ == "__main__":
    main()
