"""Benchmark end to end (small), and the paper's coupling finding as a property test."""

import json
import zlib

import numpy as np
import pytest
import torch

from calib_eval.benchmark.analysis import PROFILES, coupling_index, distribution_metrics
from calib_eval.cli import run as calib_cli


def test_two_trial_benchmark_two_configs(tmp_path):
    out = tmp_path / "bench"
    rc = calib_cli(
        ["benchmark", "--configs", "FoV200_0", "FoV220_90", "--trials", "2", "--frames", "80", "--workers", "1", "--out", str(out)]
    )
    assert rc == 0
    res = json.loads((out / "results.json").read_text())["summary"]
    assert set(res) == {"FoV200_0", "FoV220_90", "overall"}
    trials = json.loads((out / "trials.json").read_text())
    assert [(t["config"], t["trial"]) for t in trials] == [("FoV200_0", 0), ("FoV200_0", 1), ("FoV220_90", 0), ("FoV220_90", 1)]
    assert all(t["seed"] == zlib.crc32(f"{t['config']}/{t['trial']}".encode()) for t in trials)  # deterministic trials
    variants = ("all", "selector", "random", "ba_only")
    for v in variants:
        assert res["overall"][v]["n"] == 4
        # The summary is the trials' figures: success rates, and errors averaged over strict successes.
        for cfg in ("FoV200_0", "FoV220_90", "overall"):
            rs = [t[v] for t in trials if cfg in ("overall", t["config"])]
            assert res[cfg][v]["sr"] == pytest.approx(100 * np.mean([r["success"] for r in rs]))
            assert res[cfg][v]["strict_sr"] == pytest.approx(100 * np.mean([r["strict"] for r in rs]))
            strict = [r for r in rs if r["strict"]]
            if strict:
                assert res[cfg][v]["ext_mm"] == pytest.approx(np.mean([r["ext_mm"] for r in strict]))
        # Strict success means what it says: the figures are within the criteria.
        for t in trials:
            r = t[v]
            ok = r["success"] and r["intr_px"] < 2.0 and r["ext_mm"] < 5.0 and r["ext_deg"] < 0.5 and r["ate_mm"] < 50.0
            assert r["strict"] == bool(ok)
    # The easy configuration (200 degrees, parallel cameras) calibrates strictly with every method,
    # and the selector on every trial, close to the truth (measured: <= 0.51 px, <= 0.19 mm, <= 0.07 deg).
    for t in trials:
        easy = t["config"] == "FoV200_0"
        for v in variants if easy else ("selector",):
            assert t[v]["success"] and t[v]["reason"] == "ok" and t[v]["strict"], (t["config"], t["trial"], v, t[v])
        sel = t["selector"]
        assert sel["intr_px"] < 1.0 and sel["ext_mm"] < 1.0 and sel["ext_deg"] < 0.2, (t["config"], sel)
        # 0.3 px noise per coordinate is 0.42 px per corner; the ds model's misfit to the f-theta
        # lenses adds some at 220 degrees (measured 0.45-0.57 px).
        assert 0.4 < min(sel["rms_px"]) and max(sel["rms_px"]) < 0.7
    assert res["overall"]["selector"]["sr"] == 100 and res["overall"]["selector"]["strict_sr"] == 100
    assert res["FoV200_0"]["all"]["strict_sr"] == 100
    table = (out / "results.md").read_text()
    assert "CO-Calib (selector)" in table and "Strict success" in table and "paper SR" in table
    assert "| FoV200_0 | CO-Calib (selector) | 100% | 100% |" in table
    assert calib_cli(["analysis", "--benchmark", str(out), "--out", str(tmp_path / "an")]) == 0
    assert (tmp_path / "an" / "coupling_index.png").is_file() and (tmp_path / "an" / "gamma_trajectories.png").is_file()


@pytest.mark.parametrize("family", ["ucm", "eucm", "ds"])
@pytest.mark.parametrize("fov", [180, 220, 240])
def test_radial_cover_decouples_focal_and_shape(family, fov):
    radial = coupling_index(family, fov, PROFILES["R"])
    for band in ("C", "M", "E"):
        assert radial < coupling_index(family, fov, PROFILES[band])


def test_distribution_metrics_known_values():
    a = np.array([[2.0, 0.0], [0.0, 0.0]])
    b = np.array([[0.0, 0.0], [0.0, 2.0]])
    m = distribution_metrics([a, a], [b, b], permutations=50)
    assert m["D_qty"] == pytest.approx(0.0) and m["D_sp"] == pytest.approx(1.0)
    m2 = distribution_metrics([a], [2 * a], permutations=10)
    assert m2["D_qty"] == pytest.approx(1 / 3) and m2["D_sp"] == pytest.approx(0.0)


def test_timing_command_line_refuses_bad_input_before_running_anything(tmp_path, capsys):
    """``python -m calib_eval.benchmark.timing``: an unknown figure or a missing model is a one-line
    usage error (exit 2) before any benchmark runs (an unknown argument once ran them all)."""
    from calib_eval.benchmark.timing import main

    for argv in (["bogus"], ["--help-me"], ["detect", "--model", str(tmp_path / "missing.onnx")]):
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("python -m calib_eval.benchmark.timing: error:")


def test_training_step_parts_add_up_to_the_step(capsys):
    """``timing train``: every part of a training step is timed, the teacher only where the config
    has one, the step is their sum, and the profile names the convolutions the network runs."""
    from calib_eval.benchmark.timing import TRAIN_PARTS, bench_train_parts

    out = bench_train_parts("configs/tiny.yaml", ("train.batch_size=3",), repeats=1, profile=True)
    assert set(out["parts_s"]) == set(TRAIN_PARTS) and out["batch"] == 3 and out["device"] == "cpu"
    assert out["parts_s"]["teacher"] < 1e-3  # tiny.yaml has no teacher: the part is a no-op
    assert all(out["parts_s"][k] > 0 for k in TRAIN_PARTS if k != "teacher")
    assert out["step_s"] == pytest.approx(sum(out["parts_s"].values()))
    assert out["samples_per_s"] == pytest.approx(3 / out["step_s"])
    assert "convolution" in out["profile"]
    assert "training step, batch 3 at 96x64 on cpu" in capsys.readouterr().out
    assert out["trained_params"] == out["params"]


def test_training_step_parts_follow_the_recipe_of_a_distillation():
    """configs/grid_distill.yaml: the teacher runs (its part takes time), the frozen encoder is not
    trained (fewer parameters than the network has), and the architecture is the recipe's."""
    from calib_eval.benchmark.timing import bench_train_parts

    out = bench_train_parts("configs/grid_distill.yaml", ("train.batch_size=1",), repeats=1)
    assert out["parts_s"]["teacher"] > 1e-3
    assert 0 < out["trained_params"] < 0.5 * out["params"]


def test_timing_train_refuses_a_missing_config_or_device_in_one_line(tmp_path, capsys):
    from calib_eval.benchmark.timing import main

    bad = [
        ["train", "--config", str(tmp_path / "missing.yaml")],
        ["train", "--config", "configs/tiny.yaml", "--set", "train.device=tpu"],
        ["train", "--config", "configs/tiny.yaml", "--runs", "0"],
    ]
    if not torch.cuda.is_available():
        bad.append(["train", "--config", "configs/tiny.yaml", "--set", "train.device=cuda"])
    for argv in bad:
        with pytest.raises(SystemExit) as e:
            main(argv)
        assert e.value.code == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith("python -m calib_eval.benchmark.timing: error:")


def test_tag_pass_timing_names_real_stages_and_times_both_detectors(tmp_path, capsys):
    """``timing tags``: every stage it splits the tag pass into is a function of the detector (a
    renamed one would read 0 %), and on four rendered frames both detectors are timed (one image
    after another, and over the files) and the stages' shares of the tag pass's time are shares."""
    import importlib

    from calib_eval.benchmark.timing import TAG_STAGES, bench_tags

    for _, module, name in TAG_STAGES:
        assert callable(getattr(importlib.import_module(module), name)), f"{module}.{name}"
    row = bench_tags(runs=1, per_fov=1, every=1, root=tmp_path)
    assert row["images"] == 4
    assert row["tag_pass_ms"] > 0 and row["aruco_ms"] > 0
    assert row["files_ms"] > 0 and row["aruco_files_ms"] > 0  # over the files, decoding included
    assert 0 <= row["half_resolution_frames"] <= row["images"]
    shares = row["stage_share"]
    assert set(shares) == {label for label, _, _ in TAG_STAGES}
    # No stage calls another: their shares add up to at most the whole (the rest is the table's last row).
    assert all(0 <= v <= 1 for v in shares.values()) and shares["candidates"] > 0 and sum(shares.values()) <= 1
    assert "tag pass" in capsys.readouterr().out


def test_rig_corner_errors_measure_the_injected_noise():
    """The AprilGrid rig's corner check: synthetic observations of a rig at its ground truth give
    errors of zero without noise, and with Gaussian noise of sigma 0.5 px per axis a median of
    sigma * sqrt(2 ln 2) (the Rayleigh median), and none over 3 px; an id moved to its neighbour's
    corner reads that step's length."""
    from calib_eval.benchmark.aprilgrid_rig import corner_errors
    from calib_eval.benchmark.rigs import SynthSpec, make_sequence, paper_config
    from cotrain.targets import TargetConfig, make_target

    rig, target = paper_config("FoV220_90"), TargetConfig(kind="aprilgrid")
    board = make_target(target)
    clean, gt = make_sequence(rig, SynthSpec(n_frames=12, noise_px=0.0, target=target), seed=3)
    assert np.abs(corner_errors(clean, gt, board)).max() < 1e-9
    noisy, gt_n = make_sequence(rig, SynthSpec(n_frames=12, noise_px=0.5, target=target), seed=3)
    err = corner_errors(noisy, gt_n, board)
    assert len(err) > 1000
    assert abs(np.median(err) - 0.5 * np.sqrt(2 * np.log(2))) < 0.03
    assert (err > 3).sum() == 0
    o = clean.observations[0]
    k = int(np.nonzero(np.isin(o.ids + 1, o.ids))[0][0])  # a corner whose next id is seen too
    j = int(np.nonzero(o.ids == o.ids[k] + 1)[0][0])
    step = float(np.linalg.norm(o.q[j] - o.q[k]))
    o.q[k] = o.q[j]  # reported at its neighbour's place
    e = corner_errors(clean, gt, board)
    assert step > 1.0 and abs(e[k] - step) < 1e-6 and np.delete(e, k).max() < 1e-9


def test_rig_frames_with_glare_differ_from_the_clean_ones_by_a_bright_spot(tmp_path):
    """``render_rig_sequence(glare=1.0)``: every frame the same as without glare (the same scene
    and board pose) but for a spot of light on the print, which only brightens it (blurred over
    the noise, whose shot part grows with the light: by less than half a grey level anywhere
    darker); most pixels are untouched. Asking for another share of glare renders the frames again."""
    import cv2

    from calib_eval.benchmark.rendered import render_rig_sequence
    from calib_eval.benchmark.rigs import paper_config
    from cotrain.targets import TargetConfig

    rig, target = paper_config("FoV220_90"), TargetConfig(kind="aprilgrid")
    for name, glare in (("clean", 0.0), ("glare", 1.0)):
        render_rig_sequence(rig, 2, tmp_path / name, seed=11, progress=False, target=target, glare=glare)
    brighter = []
    for img in sorted((tmp_path / "clean").glob("cam*/images/*.png")):
        a = cv2.imread(str(img), cv2.IMREAD_GRAYSCALE).astype(np.float32)
        b = cv2.imread(str(tmp_path / "glare" / img.relative_to(tmp_path / "clean")), cv2.IMREAD_GRAYSCALE).astype(np.float32)
        d = cv2.GaussianBlur(b, (0, 0), 4) - cv2.GaussianBlur(a, (0, 0), 4)
        assert d.min() > -0.5 and (np.abs(b - a) <= 1).mean() > 0.75
        brighter.append((d > 20).sum())
    assert len(brighter) == 4 and min(brighter) > 100, brighter
    render_rig_sequence(rig, 2, tmp_path / "clean", seed=11, progress=False, target=target, glare=1.0)  # asked again with glare
    again = cv2.imread(str(next((tmp_path / "clean").glob("cam0/images/*.png"))), cv2.IMREAD_GRAYSCALE)
    assert np.array_equal(again, cv2.imread(str(next((tmp_path / "glare").glob("cam0/images/*.png"))), cv2.IMREAD_GRAYSCALE))


def test_training_throughput_script_measures_every_run_through_the_real_loop(tmp_path, capsys):
    """The GPU session's prepared script, on the CPU: one entry per (batch, workers, what they do)
    with the samples/s of its logged windows, written as it goes; a missing config is one line."""
    from calib_eval.benchmark.train_throughput import main

    out = tmp_path / "tt.json"
    args = ["--config", "configs/tiny.yaml", "--init", "", "--device", "cpu", "--batch", "2", "--workers", "0", "1"]
    assert main([*args, "--steps", "8", "--log-every", "2", "--threads", "1", "--out", str(out)]) == 0
    runs = json.loads(out.read_text())["runs"]
    assert [(r["batch"], r["workers"], r["workers_render"]) for r in runs] == [(2, 0, ""), (2, 1, "pixels"), (2, 1, "tables")]
    assert all(len(r["windows"]) == 4 and r["samples_per_s"] > 0 for r in runs)
    with pytest.raises(SystemExit):
        main(["--config", str(tmp_path / "none.yaml"), "--device", "cpu"])
    assert "none.yaml" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([*args, "--steps", "4", "--log-every", "2"])
    assert "--log-every windows" in capsys.readouterr().err
