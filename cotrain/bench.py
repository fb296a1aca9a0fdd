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


def bench_render_vs_step(cfg_path: str = "configs/default.yaml", repeats: int = 5) -> dict:
    """Median time to render one training batch and to run one training step on it (same process)."""
    from cotrain.config import load_config
    from cotrain.losses import compute_losses
    from cotrain.network import CornerNet
    from cotrain.train import TrainConfig, finalize_config

    cfg = finalize_config(load_config(TrainConfig, cfg_path))
    B = cfg.train.batch_size
    model = CornerNet(cfg.model)
    opt = torch.optim.AdamW(model.parameters(), lr=1e-4)
    t_render, t_step = [], []
    for r in range(repeats + 1):
        t0 = time.perf_counter()
        batch = render_batch(cfg.render, list(range(r * B, (r + 1) * B)), 77)
        t1 = time.perf_counter()
        loss = compute_losses(model(batch["image"]), batch, cfg.loss)["total"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        t2 = time.perf_counter()
        if r:  # skip warm-up
            t_render.append(t1 - t0)
            t_step.append(t2 - t1)
    mr, ms = statistics.median(t_render), statistics.median(t_step)
    out = {"render_s": mr, "step_s": ms, "ratio": mr / ms, "samples_per_s_render": B / mr, "samples_per_s_train": B / (mr + ms)}
    print(
        f"training batch {B} at {cfg.render.width}x{cfg.render.height}: render {mr * 1000:.0f} ms, step {ms * 1000:.0f} ms "
        f"(render/step = {mr / ms:.2f}); training {B / (mr + ms):.1f} samples/s, {torch.get_num_threads()} threads"
    )
    return out


def bench_detect(model: str | None = None, checkpoint: str | None = None, n: int = 12, seed: int = 99) -> dict:
    """Median ms per 1280x720 image: ``cotrain detect``'s default path (decode + onnxruntime +
    grid pass), the per-slot path (decode + onnxruntime + slot post-processing), the PyTorch
    network alone, and cv2.findChessboardCornersSB (EXHAUSTIVE | ACCURACY)."""
    import tempfile
    from pathlib import Path

    import cv2
    import numpy as np

    from cotrain.detect import Detector, load_image

    cfg = RenderConfig(height=720, width=1280)
    batch = render_batch(cfg, list(range(n)), seed)
    tmp = Path(tempfile.mkdtemp())
    paths = []
    for i in range(n):
        p = tmp / f"{i}.png"
        cv2.imwrite(str(p), (batch["image"][i, 0].numpy() * 255).astype(np.uint8))
        paths.append(p)
    out = {}
    for mode in ("grid", "slots"):
        det = Detector(model, mode=mode)
        det.detect(load_image(paths[0]))  # warm-up
        t_ort = []
        for p in paths:
            t0 = time.perf_counter()
            det.detect(load_image(p))
            t_ort.append(time.perf_counter() - t0)
        out["detector_ms" if mode == "grid" else "onnxruntime_slots_ms"] = 1000 * statistics.median(t_ort)
    if checkpoint:
        from cotrain.train import build_from_checkpoint, load_checkpoint

        net, _ = build_from_checkpoint(load_checkpoint(checkpoint))
        t_pt = []
        for p in paths:
            t0 = time.perf_counter()
            x, s = det.preprocess(load_image(p))
            with torch.no_grad():
                net(torch.from_numpy(x)[None, None])
            t_pt.append(time.perf_counter() - t0)
        out["pytorch_ms"] = 1000 * statistics.median(t_pt)
    t_cv = []
    found = 0
    flags = cv2.CALIB_CB_EXHAUSTIVE | cv2.CALIB_CB_ACCURACY
    for p in paths:
        t0 = time.perf_counter()
        img = cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)
        ok, _ = cv2.findChessboardCornersSB(img, (9, 6), flags=flags)
        t_cv.append(time.perf_counter() - t0)
        found += int(ok)
    out["findChessboardCornersSB_ms"] = 1000 * statistics.median(t_cv)
    out["speedup_vs_SB"] = out["findChessboardCornersSB_ms"] / out["detector_ms"]
    out["threads"] = torch.get_num_threads()
    print(
        f"detect on {n} rendered 1280x720 images (median ms/image): detector (onnxruntime + grid pass) {out['detector_ms']:.1f}, "
        f"onnxruntime + per-slot read-out {out['onnxruntime_slots_ms']:.1f}"
        + (f", PyTorch network {out['pytorch_ms']:.1f}" if "pytorch_ms" in out else "")
        + f", findChessboardCornersSB {out['findChessboardCornersSB_ms']:.1f} (found the board in {found}/{n}); "
        f"the detector is {out['speedup_vs_SB']:.1f}x faster than SB"
    )
    return out
