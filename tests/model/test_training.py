"""Training behaviour on the tiny config: overfitting, exact resume, 2-process gloo."""

import multiprocessing
import os
import socket
import subprocess
import sys

import pytest
import torch

from cotrain.config import ConfigError, load_config
from cotrain.model.losses import compute_losses
from cotrain.model.network import CornerNet
from cotrain.model.train import BatchesAhead, TrainConfig, TrainingBatches, build_from_checkpoint, finalize_config, load_checkpoint, train
from cotrain.render.renderer import render_batch
from cotrain.targets import make_target
from tests.paths import ROOT, TINY


def tiny(tmp_path, *overrides):
    return finalize_config(load_config(TrainConfig, TINY, [f"train.out_dir={tmp_path}", *overrides]))


def test_forward_keys_and_shapes():
    cfg = tiny("/tmp/unused")
    m = CornerNet(cfg.model)
    out = m(torch.rand(2, 1, 64, 96))
    N = 54
    assert out["heatmap"].shape == (2, N, 16, 24)
    for k in ("corners_rough", "corners_updated", "corners"):
        assert out[k].shape == (2, N, 2)
    for k in ("visibility_logit", "learnability", "confidence_logit"):
        assert out[k].shape == (2, N)


def test_overfits_fixed_batch():
    torch.manual_seed(0)
    cfg = tiny("/tmp/unused")
    cfg.render.distance_range = (0.1, 0.2)
    batch = render_batch(cfg.render, [0, 1], seed=4)
    model = CornerNet(cfg.model)
    opt = torch.optim.AdamW(model.parameters(), lr=3e-3)
    first = None
    for _ in range(150):
        loss = compute_losses(model(batch["image"]), batch, cfg.loss)["total"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        first = first if first is not None else loss.item()
    assert loss.item() < first / 5


def test_resume_matches_uninterrupted(tmp_path):
    torch.set_num_threads(1)
    a = train(tiny(tmp_path / "a", "train.steps=4", "train.ckpt_minutes=0"))
    train(tiny(tmp_path / "b", "train.steps=4", "train.stop_after=3", "train.ckpt_minutes=0"))
    ck = load_checkpoint(tmp_path / "b" / "last.pt")
    assert ck["step"] == 3
    assert (tmp_path / "a" / "curve.csv").is_file() and (tmp_path / "a" / "curve.png").is_file()
    b = train(tiny(tmp_path / "b", "train.steps=4", "train.ckpt_minutes=0"), resume=True)
    assert b["step"] == 4
    assert abs(a["last_loss"] - b["last_loss"]) < 1e-5 * max(1.0, abs(a["last_loss"]))
    # The checkpoint rebuilds the model on its own.
    model, cfg = build_from_checkpoint(load_checkpoint(tmp_path / "b" / "last.pt"))
    assert cfg.model.n_corners == 54 and isinstance(model, CornerNet)


def test_time_chunks_resume_like_an_uninterrupted_run(tmp_path):
    """train.stop_after_minutes ends a process with a checkpoint once its time is up (here after
    its first step); --resume goes on as if the run had not stopped."""
    torch.set_num_threads(1)
    a = train(tiny(tmp_path / "a", "train.steps=3", "train.ckpt_minutes=0"))
    chunk = ("train.steps=3", "train.ckpt_minutes=60", "train.stop_after_minutes=0.000001")
    assert train(tiny(tmp_path / "b", *chunk))["step"] == 1
    assert load_checkpoint(tmp_path / "b" / "last.pt")["step"] == 1
    assert train(tiny(tmp_path / "b", *chunk), resume=True)["step"] == 2
    b = train(tiny(tmp_path / "b", *chunk), resume=True)
    assert b["step"] == 3
    assert abs(a["last_loss"] - b["last_loss"]) < 1e-5 * max(1.0, abs(a["last_loss"]))


def test_render_workers_train_like_the_training_process(tmp_path):
    """Batches rendered ahead by worker processes are the batches the training process renders:
    the same run, step for step (a resume included: the workers start at the resumed step)."""
    torch.set_num_threads(1)
    a = train(tiny(tmp_path / "a", "train.steps=3", "train.ckpt_minutes=0", "train.curriculum_steps=1"))
    train(
        tiny(
            tmp_path / "b",
            "train.steps=3",
            "train.stop_after=2",
            "train.ckpt_minutes=0",
            "train.curriculum_steps=1",
            "train.render_workers=2",
        )
    )
    b = train(
        tiny(tmp_path / "b", "train.steps=3", "train.ckpt_minutes=0", "train.curriculum_steps=1", "train.render_workers=1"), resume=True
    )
    assert b["step"] == 3
    assert abs(a["last_loss"] - b["last_loss"]) < 1e-5 * max(1.0, abs(a["last_loss"]))
    # Workers that only draw (the pixels rendered here, as on a GPU) train the same run too.
    tables = ("train.render_workers=2", "train.workers_render=tables")
    c = train(tiny(tmp_path / "t", "train.steps=3", "train.ckpt_minutes=0", "train.curriculum_steps=1", *tables))
    assert c["step"] == 3 and abs(a["last_loss"] - c["last_loss"]) < 1e-5 * max(1.0, abs(a["last_loss"]))
    with pytest.raises(ConfigError, match="render_workers"):
        tiny(tmp_path / "c", "train.render_workers=-1")
    with pytest.raises(ConfigError, match="workers_render"):
        tiny(tmp_path / "c", "train.workers_render=gpu")


def test_render_workers_stop_cleanly_when_a_chunk_ends(tmp_path):
    """A chunk whose time is up while render workers have batches in flight
    (train.stop_after_minutes) stops them cleanly: the command exits 0 with its checkpoint, and
    no worker is killed (on an H200 the DataLoader's workers were, 'killed by signal: Aborted')."""
    args = [
        "train.steps=100000",
        "train.render_workers=2",
        "train.stop_after_minutes=0.25",
        "train.val_every=100000",
        "train.ckpt_minutes=60",
    ]
    r = subprocess.run(
        [sys.executable, "-m", "cotrain.cli", "train", "--config", str(TINY), f"train.out_dir={tmp_path}", *args],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert "killed by signal" not in r.stderr and "Traceback" not in r.stderr
    assert 0 < load_checkpoint(tmp_path / "last.pt")["step"] < 100000


def test_render_workers_stop_when_the_loop_fails(tmp_path):
    """Leaving the workers on an error (here an interrupt after the first batch) lets the
    workers finish the batches they hold, drops the rest and waits for every worker to exit; the batches they rendered are the
    training process's own."""
    cfg = tiny(tmp_path)
    cpu = torch.device("cpu")
    jobs = TrainingBatches(cfg.render, cfg.render, cfg.train, make_target(cfg.render.target), 1, 0, cpu)
    before = set(multiprocessing.active_children())
    with pytest.raises(KeyboardInterrupt), BatchesAhead(jobs, range(3, 1000), 2, cpu) as ahead:
        first = next(ahead)
        assert len(set(multiprocessing.active_children()) - before) == 2
        raise KeyboardInterrupt
    assert set(multiprocessing.active_children()) <= before
    assert torch.equal(first["image"], jobs[3]["image"]) and torch.equal(first["corners"], jobs[3]["corners"])
    with BatchesAhead(jobs, range(3, 1000), 1, cpu, pixels=False) as ahead:  # workers draw, this process renders
        drawn = next(ahead)
    assert set(multiprocessing.active_children()) <= before
    assert all(torch.equal(drawn[k], first[k]) for k in first)


def test_device_names_are_checked_before_training(tmp_path):
    with pytest.raises(ConfigError, match="not a torch device"):
        tiny(tmp_path, "train.device=gpu0")
    if not torch.cuda.is_available():
        with pytest.raises(ConfigError, match="no CUDA device"):
            tiny(tmp_path, "train.device=cuda")
    r = subprocess.run(
        [sys.executable, "-m", "cotrain.cli", "train", "--config", str(TINY), "--device", "gpu0", f"train.out_dir={tmp_path}"],
        capture_output=True,
        text=True,
        cwd=ROOT,
        timeout=120,
    )
    assert r.returncode != 0 and "Traceback" not in r.stderr and "not a torch device" in r.stderr


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a CUDA device")
def test_cuda_renders_and_trains_like_the_cpu(tmp_path):
    """On a GPU the batches are rendered there, the same samples as on the CPU, and a few steps
    train (the checkpoint holds CPU tensors); with a render worker, the CPU's batches train there."""
    cfg = tiny(tmp_path)
    cpu = render_batch(cfg.render, [0, 1, 2, 3], seed=5)
    gpu = render_batch(cfg.render, [0, 1, 2, 3], seed=5, device="cuda")
    assert gpu["image"].is_cuda and gpu["corners"].is_cuda
    assert torch.equal(cpu["visible"], gpu["visible"].cpu())
    assert (cpu["image"] - gpu["image"].cpu()).abs().mean() < 2e-3
    for key in ("corners", "corners_raw", "square_px", "learnability", "T_cam_board"):
        assert torch.allclose(cpu[key].double(), gpu[key].cpu().double(), atol=1e-3), key
    for key in ("board_uv", "board_mask"):  # thresholded maps: a pixel on a threshold may flip
        assert ((cpu[key] - gpu[key].cpu()).abs() > 1e-3).float().mean() < 1e-3, key
    # A training step on batches already on the GPU waits for nothing on the host.
    model = CornerNet(cfg.model).cuda().train()
    opt = torch.optim.AdamW(model.parameters(), lr=1e-3)

    def step() -> None:
        loss = compute_losses(model(gpu["image"]), gpu, cfg.loss)["total"]
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 5.0)
        opt.step()

    step()  # warm-up: allocations, kernels chosen
    torch.cuda.set_sync_debug_mode("error")
    try:
        step()
    finally:
        torch.cuda.set_sync_debug_mode("default")
    r = train(tiny(tmp_path, "train.steps=3", "train.device=cuda", "train.ckpt_minutes=0"))
    assert r["step"] == 3 and r["last_loss"] == r["last_loss"]
    ck = torch.load(tmp_path / "last.pt", weights_only=True)  # no map_location: the tensors as saved
    tensors = list(ck["model"].values()) + [t for st in ck["optimizer"]["state"].values() for t in st.values() if torch.is_tensor(t)]
    assert tensors and all(not t.is_cuda for t in tensors)
    assert train(tiny(tmp_path, "train.steps=4", "train.device=cuda", "train.ckpt_minutes=0"), resume=True)["step"] == 4
    # Batches rendered ahead on the CPU by a worker, pinned and copied to the GPU, train there too.
    w = train(tiny(tmp_path / "workers", "train.steps=2", "train.device=cuda", "train.ckpt_minutes=0", "train.render_workers=1"))
    assert w["step"] == 2 and w["last_loss"] == w["last_loss"]
    # Workers that only draw, the pixels rendered on the GPU.
    tables = ("train.render_workers=1", "train.workers_render=tables")
    t = train(tiny(tmp_path / "tables", "train.steps=2", "train.device=cuda", "train.ckpt_minutes=0", *tables))
    assert t["step"] == 2 and t["last_loss"] == t["last_loss"]


def test_two_process_gloo(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = {**os.environ, "OMP_NUM_THREADS": "1"}
    cmd = [
        sys.executable,
        "-m",
        "torch.distributed.run",
        "--nproc_per_node",
        "2",
        "--master_port",
        str(port),
        "-m",
        "cotrain.cli",
        "train",
        "--config",
        str(TINY),
        f"train.out_dir={tmp_path}",
        "train.steps=3",
        "train.save_rank_weights=true",
        "train.threads=1",
    ]
    r = subprocess.run(cmd, capture_output=True, text=True, env=env, cwd=ROOT, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    w0 = torch.load(tmp_path / "weights_rank0.pt", weights_only=True)
    w1 = torch.load(tmp_path / "weights_rank1.pt", weights_only=True)
    assert w0.keys() == w1.keys()
    for k in w0:
        assert torch.equal(w0[k], w1[k]), k
    init = CornerNet(tiny(tmp_path).model).state_dict()
    assert any(not torch.equal(init[k], w0[k]) for k in w0 if w0[k].is_floating_point())


def test_fine_tuning_adopts_checkpoint_architecture(tmp_path):
    train(tiny(tmp_path / "a", "train.steps=1", "model.identity=classify"))
    r = train(tiny(tmp_path / "b", "train.steps=1", f"train.init_from={tmp_path / 'a' / 'last.pt'}"))
    assert r["step"] == 1
    _, cfg = build_from_checkpoint(load_checkpoint(tmp_path / "b" / "last.pt"))
    assert cfg.model.identity == "classify"
    # The processing size is the recipe's, not the checkpoint's: a model fine-tuned to a smaller size.
    small = ("render.height=48", "render.width=64", "model.input_size=[48,64]")
    r = train(tiny(tmp_path / "c", "train.steps=1", f"train.init_from={tmp_path / 'a' / 'last.pt'}", *small))
    model, cfg = build_from_checkpoint(load_checkpoint(tmp_path / "c" / "last.pt"))
    assert tuple(cfg.model.input_size) == (48, 64) and cfg.model.identity == "classify"
    assert model(torch.rand(1, 1, 48, 64))["heatmap"].shape[-2:] == (12, 16)


class _BoardOracle(torch.nn.Module):
    """Stands in for the network in the validation metric: column / row logits made from the
    renderer's board coordinates (shifted by ``shift`` columns), corners exactly right."""

    def __init__(self, val: dict, shift: int):
        super().__init__()
        self.cfg = CornerNet(finalize_config(load_config(TrainConfig, TINY)).model).cfg
        self.val, self.shift = val, shift

    def forward(self, image: torch.Tensor) -> dict:
        i = next(
            k for k in range(0, self.val["image"].shape[0], image.shape[0]) if torch.equal(self.val["image"][k : k + image.shape[0]], image)
        )
        sl = slice(i, i + image.shape[0])
        uv = torch.nn.functional.avg_pool2d(self.val["board_uv"][sl], 4).round().long()
        col = torch.nn.functional.one_hot((uv[:, 0] + 1 + self.shift).clamp(0, 10), 11).permute(0, 3, 1, 2).float() * 20
        row = torch.nn.functional.one_hot((uv[:, 1] + 1).clamp(0, 7), 8).permute(0, 3, 1, 2).float() * 20
        n = self.val["corners"].shape[1]
        return {
            "corners": self.val["corners"][sl],
            "visibility_logit": torch.where(self.val["visible"][sl], 10.0, -10.0),
            "confidence_logit": torch.zeros(image.shape[0], n),
            "board_uv": uv.float(),
            "board_col_logits": col,
            "board_row_logits": row,
        }


def test_validation_board_id_accuracy_measures_column_and_row():
    from cotrain.model.train import evaluate

    cfg = finalize_config(load_config(TrainConfig, TINY))
    cfg.render.height, cfg.render.width = 216, 384
    val = render_batch(cfg.render, list(range(8)), seed=3)
    right = evaluate(_BoardOracle(val, 0), val, batch_size=4)
    wrong = evaluate(_BoardOracle(val, 1), val, batch_size=4)
    assert right["recall"] == 1.0 and right["board_id_acc"] > 0.8
    assert wrong["board_id_acc"] < 0.2


def test_trains_on_an_aprilgrid(tmp_path):
    """The same loop trains the network on Kalibr's AprilGrid: one slot per Kalibr corner id (a
    6 x 6 grid has 12 x 12 = 144) and the board head's columns and rows over the 12 x 12 corner
    grid; the checkpoint names the target and rebuilds the network alone."""
    from cotrain.targets import make_target

    torch.set_num_threads(1)
    cfg = tiny(tmp_path, "render.target.kind=aprilgrid", "model.identity=classify", "train.steps=2", "train.ckpt_minutes=0")
    assert (cfg.model.n_corners, cfg.model.grid_nx, cfg.model.grid_ny) == (144, 12, 12)
    board = make_target(cfg.render.target)
    cfg.render.distance_range = (0.3, 0.5)
    batch = render_batch(cfg.render, [0, 1, 2, 3], seed=4, board=board)
    assert batch["corners"].shape[1] == 144 and batch["visible"].any()
    out = CornerNet(cfg.model)(batch["image"])
    assert out["heatmap"].shape[1] == 144 and out["board_col_logits"].shape[1] == 12 + 2
    assert torch.isfinite(compute_losses(out, batch, cfg.loss)["total"])
    train(cfg)
    ck = load_checkpoint(tmp_path / "last.pt")
    assert ck["config"]["render"]["target"]["kind"] == "aprilgrid"
    model, cfg2 = build_from_checkpoint(ck)
    assert model.cfg.n_corners == 144 and cfg2.render.target.kind == "aprilgrid"
    # Shipping it under the checkerboard model's name, or outside export/, is refused before writing.
    from export.ship import ship

    with pytest.raises(ValueError, match="give --name"):
        ship(tmp_path / "last.pt")
    with pytest.raises(ValueError, match="plain file stem"):
        ship(tmp_path / "last.pt", "../elsewhere")


def test_bottleneck_decoder_keeps_the_outputs_and_costs_less():
    """model.decoder_bottleneck: each decoder stage squeezes its input by a 1x1 conv first; every
    output keeps its shape, so the heads of a plain model load into it, and the decoder has fewer
    weights."""
    cfg = tiny("/tmp/unused", "model.identity=classify")
    plain = CornerNet(cfg.model)
    cfg.model.decoder_bottleneck = 4
    slim = CornerNet(cfg.model)
    x = torch.rand(2, 1, 64, 96)
    a, b = plain.eval()(x), slim.eval()(x)
    assert a.keys() == b.keys()
    assert all(a[k].shape == b[k].shape for k in a)

    def weights(m, prefix):
        return sum(p.numel() for n, p in m.named_parameters() if n.startswith(prefix))

    assert weights(slim, "dec") < weights(plain, "dec")
    heads = [n for n, _ in plain.named_parameters() if not n.startswith("dec")]
    assert all(plain.state_dict()[n].shape == slim.state_dict()[n].shape for n in heads)


def test_student_from_a_teacher_frozen_encoder(tmp_path):
    """A student (another decoder) starts from its teacher's matching tensors (init_partial), its
    frozen modules keep their weights and BatchNorm statistics, the teacher's dense maps enter the
    loss (distill_dense), and the checkpoint rebuilds the student's architecture."""
    train(tiny(tmp_path / "t", "train.steps=2", "model.identity=classify"))
    teacher = tmp_path / "t" / "last.pt"
    freeze = "train.freeze=[side,enc1,enc2,enc3,enc4,enc5,attn,ctx]"
    student = ("model.identity=classify", "model.decoder_bottleneck=4", "train.init_partial=true", f"train.init_from={teacher}")
    r = train(tiny(tmp_path / "s", "train.steps=3", *student, f"train.teacher={teacher}", "loss.distill_dense=5.0", freeze))
    assert r["step"] == 3
    t_state = load_checkpoint(teacher)["model"]
    model, cfg = build_from_checkpoint(load_checkpoint(tmp_path / "s" / "last.pt"))
    assert cfg.model.decoder_bottleneck == 4
    s_state = model.state_dict()
    for k, v in s_state.items():
        if k.split(".")[0] in ("side", "enc1", "enc2", "enc3", "enc4", "enc5", "attn", "ctx"):
            assert torch.equal(v, t_state[k]), k  # weights and running statistics alike
    trained = [k for k in s_state if k.startswith("head_") and k in t_state]
    assert trained and any(not torch.equal(s_state[k], t_state[k]) for k in trained)
    with pytest.raises(ConfigError, match="no module"):
        train(tiny(tmp_path / "x", "train.steps=1", "train.freeze=[encoder]"))
    with pytest.raises(ConfigError, match="dense maps are not"):  # a teacher of another target or identity head
        train(tiny(tmp_path / "y", "train.steps=1", f"train.teacher={teacher}", "model.identity=regress"))
