"""Speed figures the docs quote: ``make bench`` (``python -m calib_eval.benchmark.timing``) runs them all.

Rendering, a training step, the detector against findChessboardCornersSB on the same frames, and
the calibration of a 480-frame stereo sequence; each figure is a median of several runs.
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

import torch

from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
from calib_eval.calibration.calibrator import CalibConfig, calibrate
from calib_eval.calibration.selector import SelectorConfig, select
from cotrain.config import load_config
from cotrain.detect.detector import Detector
from cotrain.detect.images import load_image
from cotrain.model.losses import compute_losses
from cotrain.model.network import CornerNet
from cotrain.model.train import TrainConfig, build_from_checkpoint, finalize_config, load_checkpoint
from cotrain.render.renderer import RenderConfig, render_batch


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
        net, _ = build_from_checkpoint(load_checkpoint(checkpoint))
        t_pt = []
        for p in paths:
            t0 = time.perf_counter()
            g = load_image(p)
            x = det.letterbox(g).apply(g)
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


def bench_calibration(config: str = "FoV220_90", frames: int = 480, repeats: int = 3) -> dict:
    """Median seconds to calibrate a synthetic stereo sequence: all frames, and selector + selected subset."""

    rig = paper_config(config)
    seq, _ = make_sequence(rig, SynthSpec(n_frames=frames), seed=0)
    t_all, t_sel, t_select = [], [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        r_all = calibrate(seq, CalibConfig(fov=rig.fov))
        t_all.append(time.perf_counter() - t0)
        t0 = time.perf_counter()
        sel = select(seq, SelectorConfig(fov=rig.fov))
        t1 = time.perf_counter()
        r_sel = calibrate(seq.subset(sel.keep), CalibConfig(fov=rig.fov), order=sel.order)
        t_select.append(t1 - t0)
        t_sel.append(time.perf_counter() - t0)
    out = {
        "config": config,
        "frames": frames,
        "all_frames_s": statistics.median(t_all),
        "selected_s": statistics.median(t_sel),
        "select_only_s": statistics.median(t_select),
        "n_selected_obs": len(sel.keep),
        "n_obs": len(seq.observations),
        "success_all": r_all.success,
        "success_selected": r_sel.success,
    }
    print(
        f"calibration {config}, {frames} frames ({out['n_obs']} observations): all frames {out['all_frames_s']:.2f} s, "
        f"selector + selected ({out['n_selected_obs']} observations) {out['selected_s']:.2f} s "
        f"(selector alone {out['select_only_s']:.2f} s); median of {repeats}"
    )
    return out


def main() -> int:
    results = {
        "render_384x216": bench_render(RenderConfig(), batch=8, repeats=5),
        "render_1280x720": bench_render(RenderConfig(height=720, width=1280), batch=4, repeats=3),
        "render_vs_train_step": bench_render_vs_step(),
        "detect_1280x720": bench_detect(),
        "calibration": bench_calibration(),
    }
    out = Path("report") / "bench.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1, default=str))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
