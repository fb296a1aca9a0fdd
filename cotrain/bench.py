"""Benchmarks kept in the repo (``cotrain bench-render``; ``make bench`` runs them all)."""

from __future__ import annotations

import statistics
import time

import torch

from cotrain.renderer import RenderConfig, render_batch


def bench_render(cfg: RenderConfig, batch: int = 8, repeats: int = 5, seed: int = 123) -> dict:
    """Median seconds per rendered batch and samples per second at ``cfg``'s resolution."""
    render_batch(cfg, list(range(batch)), seed)  # warm-up
    times = []
    for r in range(repeats):
        t0 = time.perf_counter()
        render_batch(cfg, list(range((r + 1) * batch, (r + 2) * batch)), seed)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    out = {"batch": batch, "height": cfg.height, "width": cfg.width, "threads": torch.get_num_threads(),
           "median_s_per_batch": med, "samples_per_s": batch / med, "runs": times}
    print(f"render {cfg.width}x{cfg.height} batch {batch}: median {med * 1000:.1f} ms/batch "
          f"({batch / med:.1f} samples/s) over {repeats} runs, {torch.get_num_threads()} threads")
    return out
