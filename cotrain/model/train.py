"""Training on online rendered data: ``cotrain train --config configs/<name>.yaml [key=value ...]``.

One linear loop (nanoGPT style). Runs data-parallel under ``torchrun --nproc_per_node N`` (gloo,
CPU). Checkpoints are written atomically, carry their config, and ``--resume`` continues exactly
(model, optimizer, schedule, step, RNG; the data stream is a function of (seed, sample index)).
"""

from __future__ import annotations

import contextlib
import csv
import dataclasses
import math
import os
import time
from collections import deque
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
from torch import Tensor

from cotrain.config import ConfigError, from_dict, load_config, to_dict
from cotrain.geometry.letterbox import CELLS
from cotrain.model.losses import LossConfig, compute_losses
from cotrain.model.network import CornerNet, ModelConfig
from cotrain.progress import progress_bar
from cotrain.render.draws import to_device
from cotrain.render.renderer import Prepared, RenderConfig, prepare_batch, render_batch, render_prepared
from cotrain.targets import Target, make_target


@dataclass
class TrainSettings:
    steps: int = 20000  # optimisation steps in total (the schedule spans them)
    batch_size: int = 8  # samples per step per process
    lr: float = 2e-3  # peak learning rate (AdamW)
    weight_decay: float = 1e-4  # AdamW weight decay
    warmup_steps: int = 300  # linear warm-up
    min_lr_ratio: float = 0.05  # cosine decays to lr * this
    grad_clip: float = 5.0  # global gradient-norm clip (0 = off)
    seed: int = 0  # data stream and initialisation seed
    val_size: int = 64  # fixed rendered validation images
    val_seed: int = 1_000_000  # validation stream seed (disjoint from training)
    val_every: int = 500  # steps between validations
    log_every: int = 20  # steps between scalar logs
    image_every: int = 1000  # steps between image panels in TensorBoard
    ckpt_minutes: float = 5.0  # wall minutes between checkpoints
    out_dir: str = "runs/default"  # checkpoints, TensorBoard logs, curve.csv
    init_from: str = ""  # checkpoint to start from (fine-tuning); ignored on --resume
    init_partial: bool = False  # init_from: the recipe's architecture, the checkpoint's tensors of the same name and shape
    teacher: str = ""  # checkpoint whose outputs are soft targets (loss.distill_dense weighs them); it runs frozen beside the model
    freeze: list[str] = field(default_factory=list)  # top-level modules (enc1, attn, ...) not trained, BatchNorm statistics kept
    save_rank_weights: bool = False  # debug: write each rank's final weights (DDP test)
    threads: int = 0  # torch threads per process (0 = leave torch's default)
    select_by: str = "recall"  # validation figure that picks best.pt: "recall" (per-slot path) or "board_id_acc" (grid pass)
    stop_after: int = 0  # stop (with a checkpoint) after this step, as if interrupted (0 = run to the end)
    stop_after_minutes: float = 0.0  # stop with a checkpoint after this many minutes of this process (0 = no limit)
    device: str = "cpu"  # where the model trains and the batches are rendered: "cpu", "cuda", "cuda:1", ...
    render_workers: int = 0  # processes rendering batches ahead on the CPU (0: the training process renders them, on train.device)
    workers_render: str = (
        "pixels"  # what render workers do: "pixels" (whole batches, on the CPU) or "tables" (draws and labels; the pixels on train.device)
    )
    curriculum_steps: int = 0  # before this step, train on closer, less cropped boards (identity is learned there first)
    curriculum_distance: tuple[float, float] = (0.1, 0.45)  # render.distance_range during the curriculum
    curriculum_offaxis_margin_deg: float = -10.0  # render.offaxis_margin_deg during the curriculum (negative: inside the FoV)


@dataclass
class TrainConfig:
    render: RenderConfig = field(default_factory=RenderConfig)  # the online renderer (its size = processing size)
    model: ModelConfig = field(default_factory=ModelConfig)  # the network
    loss: LossConfig = field(default_factory=LossConfig)  # loss weights
    train: TrainSettings = field(default_factory=TrainSettings)  # the optimisation


def finalize_config(cfg: TrainConfig) -> TrainConfig:
    """Tie the model to the target and the render size; reject inconsistent settings."""
    board = make_target(cfg.render.target)
    cfg.model.n_corners = board.n_corners
    cfg.model.grid_nx = board.nx
    cfg.model.grid_ny = board.ny
    if tuple(cfg.model.input_size) != (cfg.render.height, cfg.render.width):
        raise ConfigError(f"model.input_size {tuple(cfg.model.input_size)} must equal (render.height, render.width)")
    if cfg.train.batch_size < 1 or cfg.train.steps < 1:
        raise ConfigError("train.batch_size and train.steps must be positive")
    if cfg.train.render_workers < 0:
        raise ConfigError(f"train.render_workers must be 0 or more, not {cfg.train.render_workers}")
    if cfg.train.workers_render not in ("pixels", "tables"):
        raise ConfigError(f"train.workers_render must be 'pixels' or 'tables', not {cfg.train.workers_render!r}")
    if cfg.train.select_by not in ("recall", "board_id_acc"):
        raise ConfigError(f"train.select_by must be 'recall' or 'board_id_acc', not {cfg.train.select_by!r}")
    train_device(cfg.train)
    return cfg


def train_device(s: TrainSettings) -> torch.device:
    """The device of ``train.device``; a clear error where it does not exist here."""
    try:
        dev = torch.device(s.device)
    except (RuntimeError, TypeError):
        raise ConfigError(f"train.device {s.device!r} is not a torch device (cpu, cuda, cuda:1, ...)") from None
    if dev.type == "cuda" and not torch.cuda.is_available():
        raise ConfigError(f"train.device {s.device!r}: this torch has no CUDA device (torch {torch.__version__})")
    if dev.type == "cuda" and (dev.index or 0) >= torch.cuda.device_count():
        raise ConfigError(f"train.device {s.device!r}: only {torch.cuda.device_count()} CUDA device(s) here")
    if dev.type not in ("cpu", "cuda"):
        raise ConfigError(f"train.device {s.device!r}: only cpu and cuda are supported")
    return dev


def build_from_checkpoint(ckpt: dict) -> tuple[CornerNet, TrainConfig]:
    """Rebuild the model from a checkpoint alone (it carries its config)."""
    cfg = from_dict(TrainConfig, ckpt["config"])
    model = CornerNet(cfg.model)
    model.load_state_dict(ckpt["model"])
    return model.eval(), cfg


def load_checkpoint(path: str | Path) -> dict:
    p = Path(path)
    if not p.is_file():
        raise FileNotFoundError(f"{path}: checkpoint not found")
    try:
        return torch.load(p, map_location="cpu", weights_only=True)
    except Exception as e:  # a truncated or foreign file
        raise ValueError(f"{path}: not a cotrain checkpoint ({type(e).__name__})") from None


def load_matching(model: torch.nn.Module, state: dict[str, Tensor]) -> int:
    """Load the tensors of ``state`` whose name and shape the model has (the rest keep their
    initialisation); returns how many were loaded."""
    own = model.state_dict()
    match = {k: v for k, v in state.items() if k in own and own[k].shape == v.shape}
    own.update(match)
    model.load_state_dict(own)
    return len(match)


def _on_cpu(obj):
    """A state dict (nested dicts and lists of tensors and plain values) with every tensor on the CPU."""
    if isinstance(obj, Tensor):
        return obj.detach().cpu()
    if isinstance(obj, dict):
        return {k: _on_cpu(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return type(obj)(_on_cpu(v) for v in obj)
    return obj


def _atomic_save(obj: dict, path: Path) -> None:
    tmp = path.with_suffix(path.suffix + ".tmp")
    torch.save(obj, tmp)
    os.replace(tmp, path)


def _lr_lambda(s: TrainSettings):
    def f(step: int) -> float:
        if step < s.warmup_steps:
            return (step + 1) / s.warmup_steps
        t = min(1.0, (step - s.warmup_steps) / max(1, s.steps - s.warmup_steps))
        return s.min_lr_ratio + (1 - s.min_lr_ratio) * 0.5 * (1 + math.cos(math.pi * t))

    return f


@torch.no_grad()
def evaluate(model: CornerNet, val: dict[str, Tensor], batch_size: int = 16, tol_px: float = 3.0) -> dict[str, float]:
    """Validation metrics at the processing resolution.

    recall: detectable corners (visible, learnability > 0.2) reported visible with the right id
    within ``tol_px``; error_px: mean error of those; id_acc: detectable corners whose slot lands
    within ``tol_px`` whatever the visibility head says; outlier_rate: reported corners that are
    not visible or over ``tol_px`` off; board_id_acc: detectable corners whose 1/4 cell the dense
    board head puts in the right column and row (what the detector's grid pass votes with).
    """
    model.eval()
    outs = []
    for i in range(0, val["image"].shape[0], batch_size):
        o = model(val["image"][i : i + batch_size])
        if o["board_col_logits"].shape[1] > 0:  # classify: the most likely column / row
            uv = torch.stack([o["board_col_logits"].argmax(1), o["board_row_logits"].argmax(1)], 1).to(o["board_uv"].dtype) - 1
        else:
            uv = o["board_uv"]
        outs.append({"corners": o["corners"], "visibility_logit": o["visibility_logit"], "board_uv": uv})
    model.train()
    q = torch.cat([o["corners"] for o in outs])
    rep = torch.cat([o["visibility_logit"] for o in outs]) > 0
    err = (q - val["corners"]).norm(dim=-1)
    det = val["visible"] & (val["learnability"] > 0.2)
    close = err < tol_px
    hit = det & rep & close
    n_det = max(1, int(det.sum()))
    n_rep = int(rep.sum())
    bad = rep & (~val["visible"] | ~close)
    uv = torch.cat([o["board_uv"] for o in outs])  # (B, 2, h, w) column / row per 1/4 cell
    h, w = uv.shape[-2:]
    cell = CELLS.to_cell(val["corners"]).round().long()
    cx, cy = cell[..., 0].clamp(0, w - 1), cell[..., 1].clamp(0, h - 1)
    bi = torch.arange(uv.shape[0], device=uv.device)[:, None].expand_as(cx)
    got = torch.stack([uv[bi, 0, cy, cx], uv[bi, 1, cy, cx]], -1).round()
    nx = model.cfg.grid_nx
    ids = torch.arange(val["corners"].shape[1], device=got.device)
    want = torch.stack([ids % nx, ids // nx], -1).to(got.dtype)
    board_ok = (got == want[None]).all(-1)
    return {
        "recall": float(hit.sum()) / n_det,
        "error_px": float(err[hit].mean()) if hit.any() else float("nan"),
        "id_acc": float((det & close).sum()) / n_det,
        "outlier_rate": float(bad.sum()) / max(1, n_rep),
        "board_id_acc": float((det & board_ok).sum()) / n_det,
        "reported": float(n_rep),
    }


def plot_curve(curve_csv: Path, out_png: Path) -> None:
    """Wall time against validation recall, identity accuracy and error (the training curve)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = list(csv.DictReader(curve_csv.open()))
    if not rows:
        return
    t = [float(r["wall_s"]) / 60 for r in rows]
    fig, ax = plt.subplots(figsize=(6, 3.6))
    ax.plot(t, [float(r["recall"]) for r in rows], "o-", label="recall (right id, <3 px, reported)")
    ax.plot(t, [float(r["id_acc"]) for r in rows], "s--", label="identity accuracy (<3 px)")
    if rows and "board_id_acc" in rows[0]:
        ax.plot(t, [float(r["board_id_acc"]) for r in rows], "^-", label="board column + row at corners (grid pass votes)")
    ax.set_xlabel("wall time (min)")
    ax.set_ylabel("fraction of detectable corners")
    ax.set_ylim(0, 1)
    ax2 = ax.twinx()
    ax2.plot(t, [float(r["error_px"]) for r in rows], "r.:", label="error of recalled (px)")
    ax2.set_ylabel("px (processing resolution)", color="r")
    fig.legend(loc="upper left", fontsize=7)
    fig.tight_layout()
    fig.savefig(out_png, dpi=100)
    plt.close(fig)


def _panel(model_out: dict[str, Tensor], images: Tensor) -> Tensor:
    """(3, H, 2W) image panel: predicted corners (green = reported) next to the input."""
    import cv2

    tiles = []
    for b in range(images.shape[0]):
        im = cv2.cvtColor((images[b, 0].cpu().numpy() * 255).astype(np.uint8), cv2.COLOR_GRAY2RGB)
        for (x, y), v in zip(model_out["corners"][b].tolist(), (model_out["visibility_logit"][b] > 0).tolist()):
            if v and 0 <= x < im.shape[1] and 0 <= y < im.shape[0]:
                cv2.circle(im, (int(round(x)), int(round(y))), 2, (0, 255, 0), -1)
        tiles.append(im)
    return torch.from_numpy(np.concatenate(tiles, 1)).permute(2, 0, 1)


def main_train(config_path: str, overrides: list[str], resume: bool = False) -> int:
    """``cotrain train``: load the config and train; returns the exit code."""
    train(finalize_config(load_config(TrainConfig, config_path, overrides)), resume=resume)
    return 0


def fine_tuned_model(cfg: TrainConfig) -> tuple[ModelConfig, dict]:
    """The model config and weights a run starts from with ``train.init_from``. The checkpoint
    carries its config; its architecture wins over the recipe's (unless ``train.init_partial``).
    The processing size is not architecture (the network is fully convolutional, attention
    included): it stays the recipe's, so a model can be fine-tuned to a smaller size."""
    ck = load_checkpoint(cfg.train.init_from)
    model_cfg = cfg.model
    if not cfg.train.init_partial:
        model_cfg = from_dict(ModelConfig, ck["config"]["model"])
        model_cfg.input_size = tuple(cfg.model.input_size)
    return model_cfg, ck["model"]


def freeze(model: CornerNet, names: list[str]) -> list[torch.nn.Module]:
    """Top-level modules ``names`` of ``model`` taken out of training (``train.freeze``); returns
    them (the loop keeps them in eval mode, so their BatchNorm statistics stay)."""
    unknown = [name for name in names if not isinstance(getattr(model, name, None), torch.nn.Module)]
    if unknown:
        raise ConfigError(f"train.freeze: the network has no module {', '.join(unknown)}")
    frozen = [getattr(model, name) for name in names]
    for m in frozen:
        m.requires_grad_(False)
    return frozen


class TrainingBatches(torch.utils.data.Dataset):
    """The training stream by step: item ``step`` is that step's batch for this rank, rendered on
    ``device`` (the curriculum's scenes before ``train.curriculum_steps``). A pure function of the
    step, so worker processes rendering on the CPU give the batches the training process renders
    on the CPU exactly; a GPU renders the same scenes to within float rounding. The two halves of
    an item can run in two processes: :meth:`prepare` (the draws and labels, CPU) and
    :meth:`render` (the pixels, on ``device``)."""

    def __init__(
        self, full: RenderConfig, easy: RenderConfig, s: TrainSettings, board: Target, world: int, rank: int, device: torch.device
    ):
        self.full, self.easy, self.s, self.board = full, easy, s, board
        self.world, self.rank, self.device = world, rank, device

    def __len__(self) -> int:
        return self.s.steps

    def _render_config(self, step: int) -> RenderConfig:
        return self.easy if step < self.s.curriculum_steps else self.full  # validation always uses the full one

    def prepare(self, step: int) -> tuple[int, Prepared]:
        """The CPU half of the step's batch: (step, its scenes, tables and labels)."""
        first = (step * self.world + self.rank) * self.s.batch_size
        return step, prepare_batch(self._render_config(step), list(range(first, first + self.s.batch_size)), self.s.seed, self.board)

    def render(self, prepared: tuple[int, Prepared]) -> dict[str, torch.Tensor]:
        """The pixels of a prepared batch on ``device``."""
        step, half = prepared
        batch = render_prepared(self._render_config(step), self.board, half, self.device)
        batch.pop("params")  # per-sample camera parameters (a list): not trained on
        return batch

    def __getitem__(self, step: int) -> dict[str, torch.Tensor]:
        return self.render(self.prepare(step))


def _one_thread() -> None:
    torch.set_num_threads(1)  # a render worker: one core each, the training process keeps its own


class BatchesAhead:
    """The batches of ``steps`` in order, prepared ahead by ``workers`` processes on the CPU (one
    thread each, spawned: none inherits the parent's CUDA context or threads). ``pixels``: the
    workers render whole batches, moved to ``dev`` through pinned memory without a host sync;
    otherwise they do the draws and labels (:meth:`TrainingBatches.prepare`) and this process
    renders the pixels on ``jobs.device``. Two batches per worker are kept waiting.

    A context manager: leaving it (the run's end, a chunk's time up, an error) lets the batches
    already handed to the workers finish (about two per worker), drops the rest and waits for
    every worker to exit, so no worker is killed in the middle of a batch. A worker that dies is a
    one-line error."""

    def __init__(self, jobs: TrainingBatches, steps: range, workers: int, dev: torch.device, pixels: bool = True):
        self.jobs, self.steps, self.dev, self.pixels = jobs, iter(steps), dev, pixels
        ctx = torch.multiprocessing.get_context("spawn")
        self.pool = ProcessPoolExecutor(max_workers=workers, mp_context=ctx, initializer=_one_thread)
        self.waiting: deque = deque()
        self.depth = 2 * workers
        self._fill()

    def _fill(self) -> None:
        while len(self.waiting) < self.depth:
            step = next(self.steps, None)
            if step is None:
                return
            self.waiting.append(self.pool.submit(self.jobs.__getitem__ if self.pixels else self.jobs.prepare, step))

    def __iter__(self) -> BatchesAhead:
        return self

    def __next__(self) -> dict[str, Tensor]:
        if not self.waiting:
            raise StopIteration
        try:
            done = self.waiting.popleft().result()
        except BrokenProcessPool:
            raise RuntimeError(
                "train.render_workers: a render worker died (out of memory?); --resume goes on from the last checkpoint"
            ) from None
        self._fill()
        if not self.pixels:
            return self.jobs.render(done)
        return {k: to_device(v, self.dev) for k, v in done.items()}

    def close(self) -> None:
        """Stop: the workers finish the batches they hold, the rest are dropped, and they exit."""
        self.waiting.clear()
        self.pool.shutdown(wait=True, cancel_futures=True)

    def __enter__(self) -> BatchesAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _chunk_over(s: TrainSettings, t_process: float, world: int, dev: torch.device) -> bool:
    """Whether this process's chunk (``train.stop_after_minutes``) is up: a host check, and with
    several processes an all-reduce so that every rank stops at the same step."""
    up = time.time() - t_process > s.stop_after_minutes * 60
    if world == 1:
        return up
    flag = torch.tensor([float(up)], device=dev)
    dist.all_reduce(flag, op=dist.ReduceOp.MAX)
    return flag.item() > 0


def train(cfg: TrainConfig, resume: bool = False) -> dict:
    """The training loop. Returns {"step", "last_loss", "best_score"}."""
    t_process = time.time()  # train.stop_after_minutes counts from here: setup included
    s = cfg.train
    world = int(os.environ.get("WORLD_SIZE", "1"))
    rank = int(os.environ.get("RANK", "0"))
    dev = train_device(s)
    if dev.type == "cuda":  # one device per process: the given one, or the process's own
        if world > 1 and dev.index is not None:
            raise ConfigError(f"train.device {s.device!r}: with several processes give cuda, each takes the GPU of its LOCAL_RANK")
        local = int(os.environ.get("LOCAL_RANK", rank)) if world > 1 else torch.cuda.current_device()
        dev = torch.device("cuda", local if dev.index is None else dev.index)
        if dev.index >= torch.cuda.device_count():
            raise ConfigError(f"train.device: process {rank} wants GPU {dev.index}, but this machine has {torch.cuda.device_count()}")
        torch.cuda.set_device(dev)
    if world > 1:
        dist.init_process_group("gloo" if dev.type == "cpu" else "nccl")
    if s.threads > 0:
        torch.set_num_threads(s.threads)
    out_dir = Path(s.out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    torch.manual_seed(s.seed)

    init_state = None
    if s.init_from and not resume:
        cfg.model, init_state = fine_tuned_model(cfg)
    model = CornerNet(cfg.model).to(dev)
    frozen = freeze(model, s.freeze)

    def train_mode() -> None:
        """The model in training mode, but its frozen modules in eval mode (BatchNorm statistics kept)."""
        model.train()
        for m in frozen:
            m.eval()

    teacher = None
    if s.teacher:
        teacher, t_cfg = build_from_checkpoint(load_checkpoint(s.teacher))
        teacher.requires_grad_(False)
        teacher.to(dev)
        same = ("grid_nx", "grid_ny", "identity")
        if any(getattr(t_cfg.model, k) != getattr(cfg.model, k) for k in same):
            raise ConfigError(f"train.teacher {s.teacher}: its dense maps are not the model's (target grid or model.identity differ)")
    opt = torch.optim.AdamW([p for p in model.parameters() if p.requires_grad], lr=s.lr, weight_decay=s.weight_decay)
    sched = torch.optim.lr_scheduler.LambdaLR(opt, _lr_lambda(s))
    step, best, wall0 = 0, -1.0, 0.0
    last = out_dir / "last.pt"
    if resume:
        ck = load_checkpoint(last)
        model.load_state_dict(ck["model"])
        opt.load_state_dict(ck["optimizer"])
        sched.load_state_dict(ck["scheduler"])
        torch.set_rng_state(ck["rng"])
        step, best, wall0 = ck["step"], ck["best_score"], ck["wall_time"]
    elif init_state is not None:
        if s.init_partial:
            loaded = load_matching(model, init_state)
            if rank == 0:
                print(f"init_from {s.init_from}: {loaded} of {len(model.state_dict())} tensors loaded (same name and shape)")
        else:
            model.load_state_dict(init_state)
    train_mode()
    ddp = torch.nn.parallel.DistributedDataParallel(model, device_ids=[dev] if dev.type == "cuda" else None) if world > 1 else model

    board = make_target(cfg.render.target)
    easy = dataclasses.replace(cfg.render, distance_range=tuple(s.curriculum_distance), offaxis_margin_deg=s.curriculum_offaxis_margin_deg)
    val = render_batch(cfg.render, list(range(s.val_size)), seed=s.val_seed, board=board, device=dev) if rank == 0 else None
    writer = None
    if rank == 0:
        from torch.utils.tensorboard import SummaryWriter

        writer = SummaryWriter(str(out_dir / "tb"), purge_step=step if resume else None)
    curve_path = out_dir / "curve.csv"
    if rank == 0 and not curve_path.exists():
        curve_path.write_text("step,wall_s,recall,error_px,id_acc,outlier_rate,board_id_acc\n")

    bar = progress_bar(total=s.steps, initial=step, desc="train", unit="step", enabled=rank == 0)
    t_start = time.time() - wall0
    t_ckpt = time.time()
    t_log, n_log = time.time(), 0

    def save(path: Path) -> None:
        ck = {
            "model": _on_cpu(model.state_dict()),  # a run trained on a GPU resumes and exports anywhere
            "optimizer": _on_cpu(opt.state_dict()),
            "scheduler": sched.state_dict(),
            "rng": torch.get_rng_state(),
            "step": step,
            "best_score": best,
            "wall_time": time.time() - t_start,
            "config": to_dict(cfg),
        }
        _atomic_save(ck, path)

    end = min(s.steps, s.stop_after) if s.stop_after > 0 else s.steps
    pixels_on_workers = s.render_workers > 0 and s.workers_render == "pixels"
    jobs = TrainingBatches(cfg.render, easy, s, board, world, rank, torch.device("cpu") if pixels_on_workers else dev)
    ahead = BatchesAhead(jobs, range(step, end), s.render_workers, dev, pixels_on_workers) if s.render_workers else contextlib.nullcontext()
    last_loss = torch.tensor(float("nan"))
    first_step, saved_at = step, -1
    with ahead:  # render workers, where there are any, stop cleanly however the loop ends
        while step < end:
            chunk_over = s.stop_after_minutes > 0 and step > first_step and _chunk_over(s, t_process, world, dev)
            if chunk_over:  # checkpoint and stop; --resume goes on
                if rank == 0 and saved_at != step:
                    save(last)
                break
            batch = next(ahead) if s.render_workers else jobs[step]
            if teacher is not None:
                with torch.no_grad():
                    batch["teacher"] = teacher(batch["image"])
            out = ddp(batch["image"])
            losses = compute_losses(out, batch, cfg.loss)
            opt.zero_grad(set_to_none=True)
            losses["total"].backward()
            if s.grad_clip > 0:
                torch.nn.utils.clip_grad_norm_(model.parameters(), s.grad_clip)
            opt.step()
            sched.step()
            step += 1
            last_loss = losses["total"].detach()  # a tensor: read (a host sync on a GPU) only where logged
            n_log += s.batch_size * world
            bar.update(1)

            if rank != 0:
                continue
            if step % s.log_every == 0 or step == s.steps:
                dt = time.time() - t_log
                for k, v in losses.items():
                    if v.dim() == 0:
                        writer.add_scalar(f"loss/{k}", float(v.detach()), step)
                writer.add_scalar("train/lr", sched.get_last_lr()[0], step)
                writer.add_scalar("train/samples_per_s", n_log / max(dt, 1e-9), step)
                bar.set_postfix(loss=f"{float(losses['total'].detach()):.3f}", sps=f"{n_log / max(dt, 1e-9):.1f}")
                t_log, n_log = time.time(), 0
            if step % s.val_every == 0 or step == s.steps:
                m = evaluate(model, val)
                train_mode()
                for k, v in m.items():
                    writer.add_scalar(f"val/{k}", v, step)
                wall = time.time() - t_start
                writer.add_scalar("val/recall_vs_wall_s", m["recall"], int(wall))
                with curve_path.open("a") as f:
                    csv.writer(f).writerow(
                        [
                            step,
                            f"{wall:.1f}",
                            f"{m['recall']:.4f}",
                            f"{m['error_px']:.4f}",
                            f"{m['id_acc']:.4f}",
                            f"{m['outlier_rate']:.4f}",
                            f"{m['board_id_acc']:.4f}",
                        ]
                    )
                plot_curve(curve_path, out_dir / "curve.png")
                bar.write(
                    f"step {step}: recall {m['recall']:.3f} err {m['error_px']:.3f}px id_acc {m['id_acc']:.3f} "
                    f"outliers {m['outlier_rate']:.3f} board_id_acc {m['board_id_acc']:.3f}"
                )
                score = m[s.select_by]
                if score > best:
                    best = score
                    save(out_dir / "best.pt")
            if step % s.image_every == 0 or step == s.steps:
                with torch.no_grad():
                    model.eval()
                    o = model(val["image"][:4])
                    train_mode()
                writer.add_image("val/predictions", _panel(o, val["image"][:4]), step)
            if time.time() - t_ckpt > s.ckpt_minutes * 60 or step == end:
                save(last)
                t_ckpt, saved_at = time.time(), step
    bar.close()
    if world > 1:  # BatchNorm statistics of the last step are per rank: take rank 0's, as DDP does
        for buf in model.buffers():
            dist.broadcast(buf, 0)
    if s.save_rank_weights:
        torch.save({k: v.clone() for k, v in model.state_dict().items()}, out_dir / f"weights_rank{rank}.pt")
    if writer is not None:
        writer.close()
    if world > 1:
        dist.barrier()
        dist.destroy_process_group()
    return {"step": step, "last_loss": float(last_loss), "best_score": best}
