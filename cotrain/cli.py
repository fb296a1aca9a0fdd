"""The ``cotrain`` command: render-preview, bench-render, train (more stages as they land)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from cotrain.config import ConfigError, build, load_yaml, parse_overrides, set_dotted


def _render_config(path: str | None, overrides: list[str]):
    from cotrain.renderer import RenderConfig

    data = load_yaml(path) if path else {}
    if "render" in data:  # a full training config: take its render section
        data = data["render"] or {}
    for k, v in parse_overrides(overrides):
        set_dotted(data, k, v)
    return build(RenderConfig, data)


def cmd_render_preview(args: argparse.Namespace) -> int:
    from cotrain.preview import render_preview

    cfg = _render_config(args.config, args.overrides)
    if args.n < 1:
        raise ConfigError("--n must be at least 1")
    out = render_preview(cfg, args.n, args.out, seed=args.seed)
    print(f"wrote {out}")
    return 0


def cmd_bench_render(args: argparse.Namespace) -> int:
    from cotrain.bench import bench_render

    cfg = _render_config(args.config, args.overrides)
    bench_render(cfg, batch=args.batch, repeats=args.repeats)
    return 0


def cmd_train(args: argparse.Namespace) -> int:
    from cotrain.train import main_train

    return main_train(args.config, args.overrides, resume=args.resume)


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
    s.add_argument("overrides", nargs="*", help="key=value overrides, e.g. train.steps=100")
    s.set_defaults(func=cmd_train)
    return p


def run(argv: list[str] | None = None) -> int:
    """Parse and run; known failures become a one-line message and exit code 2."""
    args = build_parser().parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except (ConfigError, FileNotFoundError, NotADirectoryError, PermissionError, ValueError, OSError) as e:
        print(f"cotrain {args.cmd}: error: {e}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"cotrain {args.cmd}: interrupted", file=sys.stderr)
        return 130


def main() -> None:
    sys.exit(run())


if __name__ == "__main__":
    main()
