"""A synthetic rig's views rendered as images: the sequence folder a recording would give.

The rig, its cameras and the target poses come from :mod:`calib_eval.benchmark.rigs`; every view
of every camera is rendered with the renderer's appearance model (texture, lighting, noise, a
little blur), so that calibrations downstream see our detector's real corners, not projections.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import torch

from calib_eval.benchmark.rigs import GroundTruth, RigSpec, SynthSpec, make_sequence, rig_radius
from cotrain.io.sequence import Sequence
from cotrain.progress import progress_bar
from cotrain.render.renderer import RenderConfig, Scene, render_scene, sample_draws
from cotrain.targets import TargetConfig, make_target


def render_rig_sequence(
    rig: RigSpec,
    frames: int,
    seq_dir: Path,
    seed: int = 11,
    progress: bool = True,
    target: TargetConfig | None = None,
    glare: float = 0.0,
) -> tuple[Sequence, GroundTruth]:
    """Render ``frames`` synchronised views of ``rig`` into ``seq_dir`` (``camC/images``,
    ``camC/timestamps.csv``) of ``target`` (default the checkerboard), a spot of glare on the
    print in a share ``glare`` of the frames (``RenderConfig.p_glare``). Returns the noise-free
    ground-truth observations and the ground truth.

    Deterministic in (rig, seed): a longer sequence starts with the frames of a shorter one, and an
    image already in ``seq_dir`` is kept, not rendered again (an interrupted run resumes)."""
    target = target or TargetConfig()
    seq, gt = make_sequence(rig, SynthSpec(n_frames=frames, noise_px=0.0, target=target), seed=seed)
    rc = RenderConfig(
        height=rig.height, width=rig.width, p_occluder=0.0, p_no_target=0.0, p_motion=0.0, max_blur_sigma=0.6, p_glare=glare, target=target
    )
    board = make_target(rc.target)
    radius = rig_radius(rig)
    seq_dir = Path(seq_dir)
    meta = json.dumps({"rig": asdict(rig), "seed": seed, "render": asdict(rc)}, sort_keys=True, default=str)
    if (seq_dir / "render.json").is_file() and (seq_dir / "render.json").read_text() != meta:
        for d in seq_dir.glob("cam*"):  # another rig or seed: its images are not ours
            shutil.rmtree(d)
    seq_dir.mkdir(parents=True, exist_ok=True)
    (seq_dir / "render.json").write_text(meta)
    for c in range(len(gt.params)):
        d = seq_dir / f"cam{c}"
        (d / "images").mkdir(parents=True, exist_ok=True)
        lines = ["frame_id,timestamp_ns,filename"]
        for k in progress_bar(range(frames), desc=f"render cam{c}", unit="img", enabled=progress):
            name = f"{k:06d}.png"
            lines.append(f"{k},{k * 50_000_000},{name}")
            if (d / "images" / name).is_file():
                continue
            T = torch.from_numpy(gt.T_cam_rig[c] @ gt.T_rig_board[k])
            scene = Scene([gt.model[c]], [torch.from_numpy(gt.params[c])], torch.tensor([rig.fov]), torch.tensor([radius]), T[None])
            out = render_scene(rc, board, scene, [sample_draws(5000 + c, k)])
            tmp = d / "images" / f".{name}"
            cv2.imwrite(str(tmp), (out["image"][0, 0].numpy() * 255).round().astype(np.uint8))
            tmp.replace(d / "images" / name)
        (d / "timestamps.csv").write_text("\n".join(lines) + "\n")
    return seq, gt
