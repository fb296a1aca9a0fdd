"""Training throughput: samples/s of ``cotrain train`` by batch size and render workers, and how
busy the device is during a step. One prepared script for a GPU session (a few minutes):

    python -m calib_eval.benchmark.train_throughput --device cuda --batch 64 128 --workers 0 12

Each (batch, workers, what the workers do: ``--workers-render``) trains ``--steps`` steps of
``--config`` from ``--init`` (the shipped model by default) with the real loop (:func:`cotrain.model.train.train`), and its samples/s is the
median of its logged windows after the first two (start-up, the workers' spawn). On a GPU the
profiler then times ``--profile-steps`` whole steps at the first batch size, rendering on the
device included and not: the device's busy share is its kernels' time over the steps' wall time.
Figures go to ``report/train_throughput.json``.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import tempfile
import time
from pathlib import Path

import torch

from cotrain.config import ConfigError, load_config
from cotrain.model.losses import compute_losses
from cotrain.model.network import CornerNet
from cotrain.model.train import TrainConfig, TrainingBatches, finalize_config, train, train_device
from cotrain.targets import make_target


def run_config(config: str, overrides: list[str]) -> TrainConfig:
    return finalize_config(load_config(TrainConfig, config, overrides))


def logged_samples_per_s(tb_dir: Path) -> list[float]:
    """The ``train/samples_per_s`` scalars a run logged, in step order."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    acc = EventAccumulator(str(tb_dir), size_guidance={"scalars": 0})
    acc.Reload()
    return [e.value for e in acc.Scalars("train/samples_per_s")]


def measure_run(config: str, base: list[str], batch: int, workers: int, mode: str, steps: int, log_every: int) -> dict:
    """Train ``steps`` steps at ``batch`` with ``workers`` render workers doing ``mode``
    (``train.workers_render``); samples/s by window."""
    with tempfile.TemporaryDirectory() as tmp:
        overrides = [*base, f"train.batch_size={batch}", f"train.render_workers={workers}", f"train.workers_render={mode}"]
        overrides += [f"train.steps={steps}"]
        overrides += [f"train.log_every={log_every}", f"train.val_every={10 * steps}", "train.val_size=8", "train.image_every=1000000"]
        overrides += ["train.ckpt_minutes=1000", "train.curriculum_steps=0", f"train.out_dir={tmp}"]
        t0 = time.perf_counter()
        train(run_config(config, overrides))
        wall = time.perf_counter() - t0
        windows = logged_samples_per_s(Path(tmp) / "tb")
    steady = windows[2:] or windows
    out = {"batch": batch, "workers": workers, "workers_render": mode if workers else "", "steps": steps}
    out |= {"samples_per_s": statistics.median(steady), "windows": windows, "wall_s": wall}
    what = f"render workers {workers:2d} ({mode})" if workers else "rendering in the training process"
    print(f"batch {batch:4d}, {what}: {out['samples_per_s']:7.1f} samples/s (median of {len(steady)} windows)")
    return out


def device_busy_share(config: str, base: list[str], batch: int, steps: int) -> dict:
    """The device's kernel time over the wall time of ``steps`` training steps at ``batch``: with
    the batch rendered in the step (no workers), and on batches already rendered (what workers
    that keep up would give)."""
    from torch.autograd import DeviceType
    from torch.profiler import ProfilerActivity, profile

    cfg = run_config(config, [*base, f"train.batch_size={batch}"])
    dev = train_device(cfg.train)
    dev = torch.device("cuda", 0) if dev.type == "cuda" and dev.index is None else dev
    model = CornerNet(cfg.model).to(dev).train()
    opt = torch.optim.AdamW(model.parameters(), lr=cfg.train.lr)
    jobs = TrainingBatches(cfg.render, cfg.render, cfg.train, make_target(cfg.render.target), 1, 0, dev)
    ready = jobs[0]

    def step(batch_of_step: dict) -> None:
        loss = compute_losses(model(batch_of_step["image"]), batch_of_step, cfg.loss)["total"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.train.grad_clip)
        opt.step()

    def sync() -> None:
        if dev.type == "cuda":
            torch.cuda.synchronize(dev)

    def share(render: bool) -> float:
        step(ready)  # warm-up
        sync()
        with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
            t0 = time.perf_counter()
            for i in range(steps):
                step(jobs[i + 1] if render else ready)
            sync()
            wall_us = (time.perf_counter() - t0) * 1e6
        # The kernels' own events only (a launching CPU operator carries its kernels' time too).
        busy_us = sum(e.self_device_time_total for e in prof.key_averages() if e.device_type == DeviceType.CUDA)
        return busy_us / wall_us

    out = {"batch": batch, "steps": steps, "busy_rendering_in_step": share(True), "busy_batches_ready": share(False)}
    busy_render, busy_ready = out["busy_rendering_in_step"], out["busy_batches_ready"]
    print(f"device busy at batch {batch}: {busy_render:.0%} rendering in the step, {busy_ready:.0%} on batches ready")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.train_throughput", description=__doc__.splitlines()[0])
    ap.add_argument("--config", default="configs/grid.yaml", help="training config")
    ap.add_argument("--init", default="export/default.pt", help="checkpoint the runs start from (train.init_from)")
    ap.add_argument("--device", default="cuda", help="train.device (cpu: the same figures on the CPU, no busy share)")
    ap.add_argument("--batch", type=int, nargs="+", default=[64, 128], help="batch sizes")
    ap.add_argument("--workers", type=int, nargs="+", default=[0, 12], help="train.render_workers values")
    ap.add_argument(
        "--workers-render",
        nargs="+",
        default=["pixels", "tables"],
        choices=("pixels", "tables"),
        help="train.workers_render values (with workers)",
    )
    ap.add_argument("--threads", type=int, default=4, help="train.threads of the training process")
    ap.add_argument("--steps", type=int, default=60, help="steps per run")
    ap.add_argument("--log-every", type=int, default=5, help="steps per samples/s window")
    ap.add_argument("--profile-steps", type=int, default=5, help="steps under the profiler (GPU only)")
    ap.add_argument("--out", default="report/train_throughput.json", help="JSON of the figures")
    args = ap.parse_args(sys.argv[1:] if argv is None else argv)
    if args.steps < 3 * args.log_every:
        ap.error(f"--steps {args.steps}: at least three --log-every windows ({3 * args.log_every} steps), the first two are start-up")
    base = [f"train.device={args.device}", f"train.init_from={args.init}", f"train.threads={args.threads}"]
    try:
        run_config(args.config, base)
    except (ConfigError, FileNotFoundError) as e:
        ap.error(str(e))
    results = {"config": args.config, "device": args.device, "runs": []}
    for batch in args.batch:
        for workers, mode in [(w, m) for w in args.workers for m in (args.workers_render if w else ["pixels"])]:
            results["runs"].append(measure_run(args.config, base, batch, workers, mode, args.steps, args.log_every))
            Path(args.out).parent.mkdir(parents=True, exist_ok=True)
            Path(args.out).write_text(json.dumps(results, indent=1))  # what is measured is kept, run by run
    if args.device.startswith("cuda"):
        results["busy"] = device_busy_share(args.config, base, args.batch[0], args.profile_steps)
    Path(args.out).write_text(json.dumps(results, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
