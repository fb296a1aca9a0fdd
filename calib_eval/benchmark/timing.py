"""Speed figures the docs quote: ``make bench`` (``python -m calib_eval.benchmark.timing``) runs them all.

Rendering, a training step, the detector against findChessboardCornersSB on the same frames, the
AprilGrid tag pass against cv2.aruco on the same frames, and the calibration of a 480-frame
stereo sequence; each figure is a median of several runs.
``python -m calib_eval.benchmark.timing detect [--model M.onnx]`` runs the detector figures alone
(``--model``: another graph, like the int8 one of ``cotrain export --int8``, on the same frames).
``python -m calib_eval.benchmark.timing tags [--runs N]`` times the AprilGrid tag pass against
cv2.aruco on the same frames, and splits the tag pass's time into its stages.
``python -m calib_eval.benchmark.timing train [--config C] [--set train.device=cuda ...] [--profile]``
splits one training step into its parts on the training device (a GPU session's first command:
where the time of a step goes, before a run is planned).
``python -m calib_eval.benchmark.timing render [--config C]`` counts rendering's operator calls at
batch 8 and 64 and times rendering at batch 64 (how the renderer scales with the batch).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import torch

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.selector import SelectorConfig, select
from cotrain.config import ConfigError, load_config
from cotrain.detect.detector import Detector
from cotrain.detect.onnx_model import default_grid_model_path
from cotrain.model.losses import compute_losses
from cotrain.model.network import CornerNet
from cotrain.model.train import (
    TrainConfig,
    build_from_checkpoint,
    finalize_config,
    fine_tuned_model,
    freeze,
    load_checkpoint,
    train_device,
)
from cotrain.render.renderer import RenderConfig, render_batch, render_scene, sample_draws, sample_scene
from cotrain.targets import make_target


def bench_render(cfg: RenderConfig, batch: int = 8, repeats: int = 5, seed: int = 123) -> dict:
    """Median seconds per rendered batch and samples per second at ``cfg``'s resolution."""
    render_batch(cfg, list(range(batch)), seed)  # warm-up
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        render_batch(cfg, list(range((r + 1) * batch, (r + 2) * batch)), seed)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    out = {
        "batch": batch,
        "height": cfg.height,
        "width": cfg.width,
        "threads": torch.get_num_threads(),
        "median_s_per_batch": med,
        "samples_per_s": batch / med,
        "runs": times,
    }
    print(
        f"render {cfg.width}x{cfg.height} batch {batch}: median {med * 1000:.1f} ms/batch "
        f"({batch / med:.1f} samples/s) over {repeats} runs, {torch.get_num_threads()} threads"
    )
    return out


def count_render_ops(cfg: RenderConfig, batch: int, seed: int = 321) -> int:
    """Operator calls (every ``torch.profiler`` CPU event, nested ones included) of rendering one
    batch of ``batch`` samples on the CPU, after a warm-up batch."""
    from torch.profiler import ProfilerActivity, profile

    render_batch(cfg, list(range(batch)), seed)
    with profile(activities=[ProfilerActivity.CPU]) as prof:
        render_batch(cfg, list(range(batch, 2 * batch)), seed)
    return sum(e.count for e in prof.key_averages())


def bench_render_batching(config: str = "configs/grid.yaml", batches: tuple[int, int] = (8, 64), runs: int = 5) -> dict:
    """How rendering grows with the batch, on ``config``'s renderer: operator calls at each of
    ``batches`` (:func:`count_render_ops`; their ratio is what batching saves) and samples/s at
    the larger batch (median of ``runs``)."""
    cfg = load_config(TrainConfig, config, []).render
    ops = {b: count_render_ops(cfg, b) for b in batches}
    small, large = batches
    speed = bench_render(cfg, batch=large, repeats=runs)
    out = {"config": config, "op_calls": ops, "op_ratio": ops[large] / ops[small], "render": speed}
    print(f"render op calls on {config}: {ops[small]} at batch {small}, {ops[large]} at batch {large} ({out['op_ratio']:.2f}x)")
    return out


TRAIN_PARTS = ("scene_draws", "render", "teacher", "forward", "losses", "backward", "optimizer")


def bench_train_parts(
    config: str = "configs/default.yaml", overrides: tuple[str, ...] = (), repeats: int = 5, profile: bool = False
) -> dict:
    """Median seconds of each part of one training step, as ``cotrain train`` runs it on
    ``train.device`` (give ``train.device=cuda`` among ``overrides``): the per-sample random draws
    of cameras and poses on the CPU (``scene_draws``), the rendering (``render``: labels on the
    CPU, pixels on the device), the frozen teacher (configs with ``train.teacher``; 0 otherwise),
    the forward pass, the losses, the backward pass and the optimizer step (gradient clipping
    included), with the run's architecture, frozen modules and threads. On a GPU every part
    ends with a synchronisation, so a part's time is its own. ``profile``: one more step under
    ``torch.profiler``, its 25 costliest operators printed and returned as ``profile``."""
    cfg = finalize_config(load_config(TrainConfig, config, list(overrides)))
    s = cfg.train
    if s.render_workers:
        raise ConfigError("train.render_workers: this times a step's parts in one process; cotrain train reports samples/s with workers")
    dev = train_device(s)
    if dev.type == "cuda" and dev.index is None:
        dev = torch.device("cuda", 0)
    if s.threads > 0:
        torch.set_num_threads(s.threads)
    board = make_target(cfg.render.target)
    if s.init_from:  # the architecture the run trains (the weights do not change the time)
        cfg.model = fine_tuned_model(cfg)[0]
    model = CornerNet(cfg.model).to(dev).train()
    for m in freeze(model, s.freeze):  # as the loop keeps them: no gradients, eval mode
        m.eval()
    n_params = sum(p.numel() for p in model.parameters())
    teacher = None
    if s.teacher:
        teacher = build_from_checkpoint(load_checkpoint(s.teacher))[0].to(dev).eval()
        teacher.requires_grad_(False)
    trained = [p for p in model.parameters() if p.requires_grad]
    opt = torch.optim.AdamW(trained, lr=s.lr, weight_decay=s.weight_decay)
    B = s.batch_size

    def sync() -> float:
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)
        return time.perf_counter()

    def step(r: int) -> list[float]:
        t = [sync()]
        draws = [sample_draws(77, i) for i in range(r * B, (r + 1) * B)]
        scene = sample_scene(cfg.render, board, draws)
        t.append(sync())
        batch = render_scene(cfg.render, board, scene, draws, dev)
        t.append(sync())
        if teacher is not None:
            with torch.no_grad():
                batch["teacher"] = teacher(batch["image"])
        t.append(sync())
        out = model(batch["image"])
        t.append(sync())
        loss = compute_losses(out, batch, cfg.loss)["total"]
        t.append(sync())
        opt.zero_grad(set_to_none=True)
        loss.backward()
        t.append(sync())
        if s.grad_clip > 0:
            torch.nn.utils.clip_grad_norm_(trained, s.grad_clip)
        opt.step()
        t.append(sync())
        return [b - a for a, b in zip(t, t[1:])]

    times = [step(r) for r in range(repeats + 1)][1:]  # the first is a warm-up
    med = {k: statistics.median(x[i] for x in times) for i, k in enumerate(TRAIN_PARTS)}
    total = sum(med.values())
    out = {"device": str(dev), "batch": B, "threads": torch.get_num_threads(), "parts_s": med, "step_s": total, "samples_per_s": B / total}
    out["trained_params"], out["params"] = sum(p.numel() for p in trained), n_params
    size = f"{cfg.render.width}x{cfg.render.height}"
    print(f"training step, batch {B} at {size} on {dev} (median of {repeats}): {total * 1000:.0f} ms, {B / total:.1f} samples/s")
    for k, v in med.items():
        print(f"  {k:12s} {v * 1000:8.1f} ms  {100 * v / total:5.1f} %")
    if profile:
        from torch.profiler import ProfilerActivity
        from torch.profiler import profile as torch_profile

        acts = [ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if dev.type == "cuda" else [])
        with torch_profile(activities=acts) as prof:
            step(repeats + 1)
        key = "self_cuda_time_total" if dev.type == "cuda" else "self_cpu_time_total"
        out["profile"] = prof.key_averages().table(sort_by=key, row_limit=25)
        print(out["profile"])
    return out


def bench_render_vs_step(cfg_path: str = "configs/default.yaml", repeats: int = 5) -> dict:
    """Median time to render one training batch and to run one training step on it: the parts of
    :func:`bench_train_parts` in two sums (draws and rendering; teacher, forward, losses, backward
    and optimizer)."""
    parts = bench_train_parts(cfg_path, repeats=repeats)
    B, p = parts["batch"], parts["parts_s"]
    mr = p["scene_draws"] + p["render"]
    ms = parts["step_s"] - mr
    out = {"render_s": mr, "step_s": ms, "ratio": mr / ms, "samples_per_s_render": B / mr, "samples_per_s_train": B / (mr + ms)}
    print(f"render/step = {mr / ms:.2f} (render {mr * 1000:.0f} ms, step {ms * 1000:.0f} ms); training {B / (mr + ms):.1f} samples/s")
    return out


@dataclass
class DetectSet:
    """A set of rendered frames the detector is timed on (the detection evaluation's renderer and
    settings, ``calib_eval.detection.evaluation``)."""

    name: str  # row name
    seed: int  # benchmark seed
    width: int
    height: int
    per_fov: int  # frames per FoV (180, 200, 220, 240)
    n_empty: int  # frames without a target
    every: int = 1  # time every n-th frame of the set


DETECT_SETS = (
    DetectSet("evaluation set (seed 2026, 1280x720)", 2026, 1280, 720, 50, 20, every=4),
    DetectSet("other seed and size (seed 31, 1024x768)", 31, 1024, 768, 12, 4),
)


def _frames(spec: DetectSet, root: Path) -> list[Path]:
    """The set's PNG files, rendered once into ``root`` (reused while the set's config is the same)."""
    from calib_eval.detection.evaluation import EvalConfig, load_or_render

    cfg = EvalConfig(per_fov=spec.per_fov, n_empty=spec.n_empty, seed=spec.seed, width=spec.width, height=spec.height, conditions=[])
    out = root / f"detect_{spec.seed}_{spec.width}x{spec.height}_{spec.per_fov}"
    meta = load_or_render(cfg, out)
    return [out / "images" / lab["image"] for lab in meta["labels"]][:: spec.every]


def bench_detect(model: str | None = None, runs: int = 5, sets: tuple[DetectSet, ...] = DETECT_SETS, root: Path = Path("report")) -> dict:
    """Milliseconds per image, decoding included, on the same frames and in the same run:

    - ``files``: ``cotrain detect`` over the files (:func:`cotrain.io.detections.detect_files`:
      the network of the next image beside the grid pass of this one): wall time / images;
    - ``one_at_a_time``: ``Detector.detect`` on one image after another (the latency of one image);
    - ``sb``: ``cv2.findChessboardCornersSB`` (EXHAUSTIVE | ACCURACY, the board's inner corners)
      on one image after another, reading included;
    - ``grid``: the grid pass alone (``Detector.finish`` on images already through the network).

    Each figure is the median over ``runs`` runs of (total time / images)."""
    import cv2

    from cotrain.detect.buffers import keep_image_buffers
    from cotrain.detect.images import load_image
    from cotrain.io.detections import detect_files

    keep_image_buffers()  # as cotrain detect runs (cotrain.detect.buffers), for every path timed here
    det = Detector(model)
    pattern = (det.target.nx, det.target.ny)
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    out = {}
    for spec in sets:
        paths = _frames(spec, root)
        n = len(paths)
        detect_files(paths[:2], det, progress=False)  # warm-up
        pending = [det.network(load_image(p)) for p in paths]
        t_files, t_one, t_sb, t_grid = [], [], [], []
        for _ in range(runs):
            t0 = time.perf_counter()
            detect_files(paths, det, progress=False, workers=0)
            t_files.append(1000 * (time.perf_counter() - t0) / n)
            t0 = time.perf_counter()
            for p in paths:
                det.detect(load_image(p))
            t_one.append(1000 * (time.perf_counter() - t0) / n)
            t0 = time.perf_counter()
            found = 0
            for p in paths:
                found += int(cv2.findChessboardCornersSB(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE), pattern, flags=flags)[0])
            t_sb.append(1000 * (time.perf_counter() - t0) / n)
            t0 = time.perf_counter()
            for pend in pending:
                det.finish(pend)
            t_grid.append(1000 * (time.perf_counter() - t0) / n)
        row = {
            "images": n,
            "files_ms": statistics.median(t_files),
            "one_at_a_time_ms": statistics.median(t_one),
            "sb_ms": statistics.median(t_sb),
            "sb_found": found,
            "grid_ms": statistics.median(t_grid),
            "runs": {"files": t_files, "one_at_a_time": t_one, "sb": t_sb, "grid": t_grid},
            "threads": os.cpu_count(),
        }
        row["speedup_files_vs_sb"] = row["sb_ms"] / row["files_ms"]
        row["speedup_one_vs_sb"] = row["sb_ms"] / row["one_at_a_time_ms"]
        out[spec.name] = row
        print(
            f"detect, {spec.name}, {n} frames (ms/image, median of {runs} runs): cotrain detect over the files "
            f"{row['files_ms']:.1f}, one image at a time {row['one_at_a_time_ms']:.1f}, findChessboardCornersSB "
            f"{row['sb_ms']:.1f} (board found in {found}/{n}); grid pass alone {row['grid_ms']:.1f}; "
            f"{row['speedup_files_vs_sb']:.1f}x SB over files, "
            f"{row['speedup_one_vs_sb']:.1f}x one at a time"
        )
    return out


# The tag pass's stages (cotrain.detect.tag_pass's module docstring), timed by the profiler in
# bench_tags: (label, module, function); a stage's time includes what it calls.
TAG_STAGES = (
    ("candidates", "cotrain.detect.tag_candidates", "tag_candidates"),
    ("ray neighbours", "cotrain.detect.tag_candidates", "axis_neighbours"),
    ("seeds", "cotrain.detect.tag_seeds", "seed_tag"),
    ("growth", "cotrain.detect.tag_growth", "grow_tag_lattice"),
    ("reading the tags", "cotrain.detect.tag_reading", "read_cells"),
    ("placement", "cotrain.detect.tag_placement", "place_board"),
    ("ray check", "cotrain.detect.tag_placement", "rays_agree"),
    ("final fits", "cotrain.detect.refinement", "final_fits"),
    ("print check", "cotrain.detect.verification", "print_check"),
    ("completion", "cotrain.detect.completion", "complete_board"),
    ("image circle", "cotrain.detect.image_circle", "fit_image_circle"),
)


def bench_tags(runs: int = 3, per_fov: int = 50, every: int = 2, root: Path = Path("report")) -> dict:
    """Milliseconds per image of the AprilGrid tag pass (``Detector(target=AprilGrid).detect``) and of
    cv2.aruco (``DICT_APRILTAG_36h11``, Kalibr's 2-bit border, the evaluation's settings) on the
    same frames in the same run, one image after another, decoding excluded: every ``every``-th
    frame of the FoV rows of the AprilGrid evaluation set (``python -m calib_eval.detection.tags``,
    rendered once into ``root``). cv2.aruco spreads its work over OpenCV's threads (every core),
    the tag pass mostly runs in one; so two more figures, decoding included, give both the
    machine's cores: ``cotrain detect`` over the files (:func:`cotrain.io.detections.detect_files`,
    a worker process per core, their start included) and cv2.aruco over the same files one after
    another. Each figure is the median over ``runs`` runs of (total time / images). One more run
    under cProfile splits the tag pass by stage (:data:`TAG_STAGES`; the profiler's overhead
    inflates them all, so they are shares, not times), and counts the frames read again at half
    resolution."""
    import cProfile
    import importlib
    import pstats

    import cv2

    from calib_eval.detection.tags import PEERS, TagEvalConfig, render_set
    from cotrain.detect.buffers import keep_image_buffers
    from cotrain.detect.detector import Detector
    from cotrain.io.detections import detect_files
    from cotrain.targets import TargetConfig, make_target

    keep_image_buffers()
    board = make_target(TargetConfig(kind="aprilgrid"))
    cfg = TagEvalConfig(per_fov=per_fov, conditions=[], n_empty=0)
    out = root / f"tags_{cfg.seed}_{per_fov}"
    labels = [lab for lab in render_set(cfg, board, out) if lab["fov"]][::every]
    paths = [out / "images" / lab["image"] for lab in labels]
    images = [cv2.imread(str(p), cv2.IMREAD_GRAYSCALE) for p in paths]
    ours = Detector(target=board)
    aruco = PEERS["aruco"]()  # as the AprilGrid evaluation runs it
    ours.detect(images[0])
    n = len(images)
    t_ours, t_aruco, t_files, t_aruco_files = [], [], [], []
    for _ in range(runs):
        t0 = time.perf_counter()
        for img in images:
            ours.detect(img)
        t_ours.append(1000 * (time.perf_counter() - t0) / n)
        t0 = time.perf_counter()
        for img in images:
            aruco(img)
        t_aruco.append(1000 * (time.perf_counter() - t0) / n)
        t0 = time.perf_counter()
        detect_files(paths, ours, progress=False, workers=0)
        t_files.append(1000 * (time.perf_counter() - t0) / n)
        t0 = time.perf_counter()
        for p in paths:
            aruco(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE))
        t_aruco_files.append(1000 * (time.perf_counter() - t0) / n)
    prof = cProfile.Profile()
    prof.enable()
    for img in images:
        ours.detect(img)
    prof.disable()
    stats = pstats.Stats(prof).stats  # {(file, line, name): (calls, prim, tottime, cumtime, callers)}
    total = sum(v[3] for k, v in stats.items() if k[2] == "detect" and k[0].endswith("detector.py"))
    stages = {}
    for label, module, name in TAG_STAGES:
        path = importlib.import_module(module).__file__
        stages[label] = sum(v[3] for k, v in stats.items() if k[2] == name and k[0] == path) / max(total, 1e-9)
    half = sum(v[0] for k, v in stats.items() if k[2] == "_tag_pass_circle") - n
    row = {
        "images": n,
        "tag_pass_ms": statistics.median(t_ours),
        "aruco_ms": statistics.median(t_aruco),
        "files_ms": statistics.median(t_files),
        "aruco_files_ms": statistics.median(t_aruco_files),
        "runs": {"tag_pass": t_ours, "aruco": t_aruco, "files": t_files, "aruco_files": t_aruco_files},
        "stage_share": stages,
        "half_resolution_frames": half,
    }
    row["ratio_vs_aruco"] = row["tag_pass_ms"] / row["aruco_ms"]
    row["files_ratio_vs_aruco"] = row["files_ms"] / row["aruco_files_ms"]
    split = ", ".join(f"{k} {100 * v:.0f} %" for k, v in stages.items())
    print(
        f"tags, {n} frames of the FoV rows (ms/image, median of {runs} runs): tag pass {row['tag_pass_ms']:.1f}, "
        f"cv2.aruco {row['aruco_ms']:.1f} ({row['ratio_vs_aruco']:.1f}x aruco's time); over the files, decoding "
        f"included, every core: cotrain detect {row['files_ms']:.1f}, cv2.aruco {row['aruco_files_ms']:.1f} "
        f"({row['files_ratio_vs_aruco']:.1f}x); read again at half resolution: "
        f"{half} frames; share of the tag pass's time (profiled): {split}"
    )
    return row


def bench_calibration(config: str = "FoV220_90", frames: int = 480, repeats: int = 3) -> dict:
    """Median seconds to calibrate a synthetic stereo sequence: all frames as before the trust
    checks (a flat board, no time offsets), all frames with everything ``calib-eval calibrate``
    does (the warp, the time-offset estimate, uncertainty, cross-validation, the verdict, report
    files), and selector + selected subset."""
    import tempfile

    from calib_eval.calibration.publish import publish

    rig = paper_config(config)
    seq, _ = make_sequence(rig, SynthSpec(n_frames=frames), seed=0)
    t_plain, t_all, t_trust, t_sel, t_select = [], [], [], [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        calibrate(seq, CalibConfig(fov=rig.fov, flat_board=True, time_offset="off"))
        t_plain.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        cfg = CalibConfig(fov=rig.fov)
        r_all = calibrate(seq, cfg)
        t1 = time.perf_counter()
        with tempfile.TemporaryDirectory() as tmp:
            publish(r_all, seq, cfg, tmp)
        t_all.append(time.perf_counter() - t0)
        t_trust.append(time.perf_counter() - t1)
        t0 = time.perf_counter()
        sel = select(seq, SelectorConfig(fov=rig.fov))
        t1 = time.perf_counter()
        r_sel = calibrate(seq.subset(sel.keep), CalibConfig(fov=rig.fov), order=sel.order)
        t_select.append(t1 - t0)
        t_sel.append(time.perf_counter() - t0)
    out = {
        "config": config,
        "frames": frames,
        "all_frames_plain_s": statistics.median(t_plain),
        "all_frames_s": statistics.median(t_all),
        "trust_and_reports_s": statistics.median(t_trust),
        "ratio_to_plain": statistics.median(t_all) / statistics.median(t_plain),
        "selected_s": statistics.median(t_sel),
        "select_only_s": statistics.median(t_select),
        "n_selected_obs": len(sel.keep),
        "n_obs": len(seq.observations),
        "success_all": r_all.success,
        "success_selected": r_sel.success,
    }
    print(
        f"calibration {config}, {frames} frames ({out['n_obs']} observations): all frames {out['all_frames_plain_s']:.2f} s "
        f"without the trust checks, {out['all_frames_s']:.2f} s with them and the report files "
        f"({out['ratio_to_plain']:.2f}x; the checks and reports {out['trust_and_reports_s']:.2f} s); selector + selected "
        f"({out['n_selected_obs']} observations) {out['selected_s']:.2f} s (selector alone {out['select_only_s']:.2f} s); "
        f"median of {repeats}"
    )
    return out


def _write_report(name: str, results: dict) -> None:
    """``report/NAME`` with the figures as JSON, and a line that says so."""
    out = Path("report") / name
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1, default=str))
    print(f"wrote {out}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.timing", description=__doc__.splitlines()[0])
    ap.add_argument(
        "what",
        nargs="?",
        choices=("all", "detect", "tags", "train", "render", "calibration"),
        default="all",
        help="all figures (make bench), the detector's, the AprilGrid tag pass's, a training step's parts, "
        "rendering's operator calls and speed by batch size, or the calibration's",
    )
    ap.add_argument("--model", help="ONNX model for the detector figures (default: the shipped model)")
    ap.add_argument("--runs", type=int, default=5, help="runs per figure (the median is quoted)")
    ap.add_argument("--config", help="train, render: the training config (default: configs/default.yaml, configs/grid.yaml)")
    ap.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="train: a config override (train.device=cuda, train.batch_size=64)"
    )
    ap.add_argument("--profile", action="store_true", help="train: one more step under torch.profiler, its costliest operators")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.model and not Path(args.model).is_file():
        ap.error(f"no model file {args.model}")
    if args.runs < 1:
        ap.error(f"--runs must be at least 1, not {args.runs}")
    if args.what == "train":
        try:
            results = bench_train_parts(args.config or "configs/default.yaml", tuple(args.set), repeats=args.runs, profile=args.profile)
        except (ConfigError, FileNotFoundError) as e:
            ap.error(str(e))
        _write_report("bench_train.json", results)
        return 0
    if args.what == "render":
        try:
            results = bench_render_batching(args.config or "configs/grid.yaml", runs=args.runs)
        except (ConfigError, FileNotFoundError) as e:
            ap.error(str(e))
        _write_report("bench_render.json", results)
        return 0
    if args.what == "tags":
        _write_report("bench_tags.json", bench_tags(runs=args.runs))
        return 0
    if args.what == "calibration":
        _write_report("bench_calibration.json", bench_calibration(repeats=args.runs))
        return 0
    if args.what == "detect":
        results = {"detect": bench_detect(args.model, runs=args.runs), "model": args.model or str(default_grid_model_path())}
        _write_report("bench_detect.json" if not args.model else f"bench_detect_{Path(args.model).stem}.json", results)
        return 0
    results = {
        "render_384x216": bench_render(RenderConfig(), batch=8, repeats=5),
        "render_1280x720": bench_render(RenderConfig(height=720, width=1280), batch=4, repeats=3),
        "render_vs_train_step": bench_render_vs_step(),
        "render_batching": bench_render_batching(),
        "detect": bench_detect(args.model, runs=args.runs),
        "tags": bench_tags(runs=args.runs),
        "calibration": bench_calibration(),
    }
    _write_report("bench.json", results)
    return 0


if __name__ == "__main__":
    sys.exit(main())
