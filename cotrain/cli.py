"""The ``cotrain`` command: detect, train, export, render-preview, bench-render, and the main job (pipeline)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cotrain.config import ConfigError, build, load_yaml, parse_overrides, set_dotted


def _render_config(path: str | None, overrides: list[str]):
    from cotrain.render.renderer import RenderConfig

    data = load_yaml(path) if path else {}
    if "render" in data:  # a full training config: take its render section
        data = data["render"] or {}
    for k, v in parse_overrides(overrides):
        set_dotted(data, k, v)
    return build(RenderConfig, data)


def cmd_render_preview(args: argparse.Namespace) -> int:
    from cotrain.render.preview import render_preview

    cfg = _render_config(args.config, args.overrides)
    if args.n < 1:
        raise ConfigError("--n must be at least 1")
    out = render_preview(cfg, args.n, args.out, seed=args.seed)
    print(f"wrote {out}")
    return 0


def cmd_bench_render(args: argparse.Namespace) -> int:
    from calib_eval.benchmark.timing import bench_render

    cfg = _render_config(args.config, args.overrides)
    bench_render(cfg, batch=args.batch, repeats=args.repeats)
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from cotrain.model.train import main_train

    overrides = args.overrides + ([f"train.device={args.device}"] if args.device else [])
    return main_train(args.config, overrides, resume=args.resume)


def cmd_export(args: argparse.Namespace) -> int:
    from export.onnx_export import export_onnx

    size = None
    if args.input_size:
        w, sep, h = args.input_size.lower().partition("x")
        if not (sep and w.isdigit() and h.isdigit()):
            raise ValueError(f"--input-size wants WIDTHxHEIGHT, not {args.input_size!r}")
        size = (int(h), int(w))
    r = export_onnx(args.checkpoint, args.out, tol_px=args.tol_px, input_size=size)
    print(
        f"wrote {r['out']} (opset {r['opset']}); parity on {r['images']} rendered images: max corner difference "
        f"{r['max_corner_diff_px']:.2e} px, max probability difference {r['max_prob_diff']:.2e}"
    )
    if args.int8:
        from export.onnx_export import quantize_dense

        q = quantize_dense(args.out, Path(args.out).with_suffix(".int8.onnx"))
        diffs = ", ".join(f"{k} {v:.3f}" for k, v in q["max_diff"].items())
        print(f"wrote {q['out']} (int8, dense maps only, for the grid pass); largest differences from float: {diffs}")
    return 0


def cmd_detect(args: argparse.Namespace) -> int:
    from cotrain.detect.detector import make_detector
    from cotrain.detect.grid_config import GREY_PRINT_GAIN, GridConfig
    from cotrain.detect.images import expand_inputs, image_folders_below
    from cotrain.detect.onnx_model import OnnxModel
    from cotrain.io.detections import detect_files, write_json_atomic
    from cotrain.io.folders import check_sequence_folder
    from cotrain.targets import AprilGrid, target_from_flags

    if not (0.0 <= args.threshold <= 1.0):
        raise ValueError("--threshold must be in [0, 1]")
    if args.workers < 0:
        raise ValueError("--workers must be 0 (one per core) or a positive number")
    if sum(map(bool, (args.inputs, args.bag, args.images))) != 1:
        raise ValueError(
            "give images or folders, --images DIR0 DIR1 ... (one folder per camera), or --bag REC --topics T0 T1 ... (one of them)"
        )
    if bool(args.topics) != bool(args.bag):
        raise ValueError("--bag and --topics go together")
    if (args.bag or args.images) and args.out:
        check_sequence_folder(args.out)
    if (args.bag or args.images) and args.draw:
        raise ValueError("--draw goes with images or folders; with --bag or --images, calib-eval calibrate draws the report")
    if args.images and args.every:
        raise ValueError("--every goes with --bag; with --images, keep the images you want in the folders")
    paths = expand_inputs(args.inputs) if args.inputs else []
    if args.inputs and not paths:
        below = [f for d in args.inputs if Path(d).is_dir() for f in image_folders_below(Path(d))]
        hint = f" (folders below hold images: {', '.join(map(str, below[:3]))}{' ...' if len(below) > 3 else ''})" if below else ""
        raise FileNotFoundError("no images found in the given paths" + hint)
    base = OnnxModel(args.model).target if args.square_size is not None and args.squares_x is None else None
    target = target_from_flags(args.target, args.squares_x, args.squares_y, args.square_size, base)
    if args.grey_print and isinstance(target, AprilGrid):
        raise ValueError("--grey-print reads a checkerboard frame again; the tag pass raises a grey print's contrast itself")
    if args.grey_print and args.slots:
        raise ValueError("--grey-print reads frames again with the grid pass; --slots does not run it")
    options = {"grid": GridConfig(retry_gain=GREY_PRINT_GAIN)} if args.grey_print else {}
    det = make_detector(
        target,
        args.model,
        threshold=args.threshold,
        consistency=not args.no_consistency,
        polish=args.polish,
        mode="slots" if args.slots else "grid",
        **options,
    )
    if args.images:
        from cotrain.io.folders import sequence_from_folders

        out = Path(args.out) if args.out else Path(str(args.images[0]).rstrip("/") + ".sequence")
        folder, read = sequence_from_folders(args.images, out, det, workers=args.workers)
        counts = ", ".join(f"{d} {n} images" for d, n in zip(args.images, read["images"]))
        cached = " (cached)" if read["cached"] else ""
        print(f"{counts}, paired by {read['pairing']} -> sequence folder {folder}{cached}")
        return 0
    if args.bag:
        from cotrain.io.bags import sequence_from_bag

        out = Path(args.out) if args.out else Path(str(args.bag).rstrip("/") + ".sequence")
        if not 0 <= args.every < float("inf"):
            raise ValueError("--every must be 0 (every image) or a positive number of seconds")
        folder, read = sequence_from_bag(args.bag, args.topics, out, det, interval_s=args.every, workers=args.workers)
        counts = ", ".join(f"{t} {n} images" for t, n in zip(args.topics, read["images"]))
        cached = " (cached)" if read["cached"] else ""
        print(f"{args.bag}: {counts}, {sum(read['skipped'])} undecodable skipped -> sequence folder {folder}{cached}")
        return 0
    data = detect_files(paths, det, Path(args.draw) if args.draw else None, workers=args.workers)
    out = Path(args.out or "detections.json")
    write_json_atomic(data, out)
    n_err = sum(1 for e in data["images"] if e["error"])
    n_found = sum(len(e["corners"]) for e in data["images"])
    print(f"{len(paths)} images, {n_found} corners, {n_err} errors -> {out}")
    for e in data["images"]:
        if e["error"]:
            print(f"  {e['path']}: {e['error']}", file=sys.stderr)
    n_none = sum(1 for e in data["images"] if not e["error"] and not e["corners"])
    if n_none > (len(paths) - n_err) / 2 and not (args.grey_print or args.slots or isinstance(target, AprilGrid)):
        print(f"hint: {n_none} of {len(paths) - n_err} images gave no corners; for a grey print, shade or dim light try --grey-print")
    return 0


def cmd_pipeline(args: argparse.Namespace) -> int:
    from calib_eval.pipeline import PipelineConfig, run_pipeline
    from cotrain.config import load_config

    cfg = load_config(PipelineConfig, args.config, args.overrides)
    return run_pipeline(cfg, from_scratch=args.from_scratch)


def _add_detect(sub) -> None:
    """``cotrain detect``: images, folders of images, image folders per camera or a bag."""
    s = sub.add_parser("detect", help="detect corners in images with the ONNX model (onnxruntime, CPU)")
    s.add_argument("inputs", nargs="*", metavar="IMAGES_OR_FOLDERS")
    s.add_argument("--bag", help="instead of images: a ROS1 .bag or ROS2 bag folder; writes a sequence folder with detections")
    s.add_argument("--topics", nargs="+", metavar="TOPIC", help="with --bag: one image topic per camera, cam0 first")
    s.add_argument(
        "--images",
        nargs="+",
        metavar="DIR",
        help="instead of images: one folder per camera, cam0 first; writes a sequence folder with detections (docs/commands.md)",
    )
    s.add_argument(
        "--every", type=float, default=0.0, metavar="SECONDS", help="with --bag: at most one image per camera per this many seconds"
    )
    s.add_argument("--model", help="ONNX model (default: the shipped model)")
    s.add_argument(
        "--out",
        help="detection JSON (default detections.json); with --bag or --images the sequence folder (default BAG.sequence, DIR0.sequence)",
    )
    s.add_argument("--threshold", type=float, default=0.5, help="with --slots: visibility probability to report a corner")
    s.add_argument("--draw", help="folder for overlays of the detections")
    s.add_argument(
        "--workers",
        type=int,
        default=0,
        help="processes over many files (default 0: one per core, up to 8; 1: this process only)",
    )
    s.add_argument(
        "--slots",
        action="store_true",
        help="experimental: the network's own per-slot corners instead of the grid pass (ids right for few corners; see docs/detector.md)",
    )
    s.add_argument("--polish", action="store_true", help="with --slots: classical saddle-point polish of the corners")
    s.add_argument("--no-consistency", action="store_true", help="with --slots: keep corners that fail the grid-consistency check")
    s.add_argument("--target", help="the board: our target config, a Kalibr target yaml or a BoofCV one (default: the model's board)")
    s.add_argument("--squares-x", type=int, help="another checkerboard than the model's: squares along x (ids from geometry alone)")
    s.add_argument("--squares-y", type=int, help="... and along its y axis")
    s.add_argument("--square-size", type=float, help="side of a square, metres (written to the JSON's target)")
    s.add_argument(
        "--grey-print",
        action="store_true",
        help="checkerboard: read a frame where no board is found again with its contrast raised (a grey print, shade, dim light; "
        "~40 ms more for each such frame; the AprilGrid's tag pass always does this)",
    )
    s.set_defaults(func=cmd_detect)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="cotrain", description="Learned fisheye calibration-target detection.")
    sub = p.add_subparsers(dest="cmd", required=True)

    s = sub.add_parser("render-preview", help="draw a grid of rendered training samples with their labels")
    s.add_argument("--config", help="YAML with renderer settings (or a training config with a render: section)")
    s.add_argument("--n", type=int, default=16, help="number of samples")
    s.add_argument("--out", default="preview.png", help="output image")
    s.add_argument("--seed", type=int, default=0)
    s.add_argument("overrides", nargs="*", help="key=value overrides of the render config")
    s.set_defaults(func=cmd_render_preview)

    s = sub.add_parser("bench-render", help="benchmark: rendered samples per second")
    s.add_argument("--config")
    s.add_argument("--batch", type=int, default=8)
    s.add_argument("--repeats", type=int, default=5)
    s.add_argument("overrides", nargs="*")
    s.set_defaults(func=cmd_bench_render)

    s = sub.add_parser("train", help="train the corner network on online rendered data")
    s.add_argument("--config", required=True, help="training config, e.g. configs/tiny.yaml")
    s.add_argument("--resume", action="store_true", help="continue from the run's last checkpoint")
    s.add_argument("--device", help="train and render on this torch device (cpu, cuda, cuda:1; default: the config's train.device, cpu)")
    s.add_argument("overrides", nargs="*", help="key=value overrides, e.g. train.steps=100 train.stop_after_minutes=9")
    s.set_defaults(func=cmd_train)

    s = sub.add_parser("export", help="export a checkpoint to ONNX (with the onnxruntime parity check)")
    s.add_argument("--checkpoint", required=True)
    s.add_argument("--out", required=True)
    s.add_argument("--tol-px", type=float, default=0.01, help="fail if onnxruntime and PyTorch corners differ by more")
    s.add_argument("--input-size", metavar="WxH", help="processing size of the graph (default: the size it was trained at)")
    s.add_argument(
        "--int8",
        action="store_true",
        help="also write OUT.int8.onnx: the grid pass's maps with int8 convolutions (as export.ship ships them)",
    )
    s.set_defaults(func=cmd_export)

    _add_detect(sub)

    s = sub.add_parser("pipeline", help="the main job: train, export, evaluate, calibrate; writes a report folder")
    s.add_argument("--config", default=None, help="pipeline YAML (default: the embedded defaults = configs/pipeline.yaml)")
    s.add_argument("--from-scratch", action="store_true", help="train from random weights instead of fine-tuning the shipped model")
    s.add_argument("overrides", nargs="*", help="key=value overrides, e.g. train_steps=50")
    s.set_defaults(func=cmd_pipeline)
    return p


TRAIN_EXTRA = ("torch", "kornia", "tensorboard", "onnxscript")  # pyproject's [train] extra


def dispatch(prog: str, args: argparse.Namespace) -> int:
    """Run a parsed sub-command; bad input (config, file, value errors) becomes a one-line message
    and exit code 2, an interrupt exit code 130. A package of the ``[train]`` extra missing from a
    base install (``pip install cotrain``) is a one-line error that names the install. Shared by ``cotrain`` and ``calib-eval``."""
    try:
        return int(args.func(args) or 0)
    except ModuleNotFoundError as e:
        if (e.name or "").split(".")[0] not in TRAIN_EXTRA:
            raise
        print(
            f"{prog} {args.cmd}: error: this command needs {e.name.split('.')[0]}, which comes with the training extra: "
            "pip install 'cotrain[train]'",
            file=sys.stderr,
        )
        return 2
    except (ConfigError, ValueError, OSError) as e:  # OSError covers missing files, folders, permissions
        print(f"{prog} {args.cmd}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{prog} {args.cmd}: interrupted", file=sys.stderr)
        return 130


def run(argv: list[str] | None = None) -> int:
    return dispatch("cotrain", build_parser().parse_args(argv))


def main() -> None:
    sys.exit(run())


if __name__ == "__main__":
    main()
