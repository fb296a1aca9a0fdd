"""The rendered detection sets (``calib_eval/detection/sets.py``): a set's seed depends on its image
size (1280x720 keeps its frames), the tuning sets are named and never described as held out."""

import dataclasses
import itertools
import json

import numpy as np
import pytest

from calib_eval.detection.sets import KEPT_SIZE, TUNING_SETS, TuningSet, describe, is_tuning, set_seed

SIZES = [(640, 480), (1024, 1024), (1280, 720), (1920, 1080), (1920, 1200)]  # the sizes of docs/results
SEEDS = [7, 11, 31, 97, 99, 2026]


def test_the_seed_depends_on_the_size_and_1280x720_keeps_its_own():
    assert all(set_seed(s, 1280, 720) == s for s in SEEDS)  # today's 1280x720 sets keep their frames
    assert set_seed(7, 1920, 1080) != set_seed(7, 1280, 720) != set_seed(7, 640, 480)
    assert set_seed(7, 1920, 1080) != set_seed(7, 1920, 1200) != set_seed(7, 1080, 1920)
    assert set_seed(7, 1920, 1080) == 7 + 7919 * 1920 + 104729 * 1080  # documented, deterministic


def test_no_two_sets_of_the_sizes_and_seeds_in_use_share_a_seed_or_a_frame():
    """Over the sizes and seeds of docs/results (and every seed a tuning set names), the sets' base
    seeds are distinct, and so are the random streams of their frames (the renderer seeds a frame's
    stream with the low 32 bits of ``sample_draws``' seed): no frame of one set is a frame of another."""
    from calib_eval.detection.conditions import CONDITIONS
    from calib_eval.detection.evaluation import BENCH_VERSION
    from cotrain.render.draws import sample_draws

    seeds = sorted(set(SEEDS) | {t.seed for t in TUNING_SETS if t.kind == "checkerboard"})
    bases = {(s, size): set_seed(s, *size) for s in seeds for size in SIZES}
    assert len(set(bases.values())) == len(bases)

    def streams(base: int) -> set[int]:  # a default set's frames (50 per FoV, 20 empty, 24 per condition), as render_benchmark seeds them
        frames = [(base * 1000 + BENCH_VERSION * 100 + fov // 10, i) for fov in (180, 200, 220, 240) for i in range(50)]
        frames += [(base * 1000 + BENCH_VERSION * 100, i) for i in range(20)]
        frames += [(base * 1000 + BENCH_VERSION * 100 + 50 + c, i) for c in range(len(CONDITIONS)) for i in range(24)]
        return {sample_draws(f, i).initial_seed() & 0xFFFFFFFF for f, i in frames}

    got = {k: streams(b) for k, b in bases.items() if k[0] in SEEDS}
    assert all(len(v) == 200 + 20 + 24 * len(CONDITIONS) for v in got.values())
    for a, b in itertools.combinations(got, 2):
        assert not got[a] & got[b], (a, b)


def test_the_tuning_sets_are_named_and_never_held_out():
    assert is_tuning("checkerboard", 7, 1280, 720) and is_tuning("checkerboard", 11, 1280, 720)
    assert is_tuning("checkerboard", 2026, 1280, 720)  # the evaluation set: thresholds were set on it too
    assert is_tuning("aprilgrid", 2027, 1280, 720)  # the AprilGrid evaluation set, likewise
    assert not is_tuning("checkerboard", 99, 1024, 1024)  # drawn anew: not the frames seen before
    # Drawn anew, then used on the same day to judge a change: a tuning set again, at that size only.
    assert is_tuning("checkerboard", 31, 640, 480) and not is_tuning("checkerboard", 31, 800, 600)
    assert not is_tuning("checkerboard", 7, 1920, 1080)  # was seed 7's scenes again; now other frames
    assert not is_tuning("aprilgrid", 7, 1280, 720) and not is_tuning("checkerboard", 2027, 1280, 720)
    # Seed 67 was tuned on at 1920x1080, when a seed drew the same scenes at every size: those
    # scenes are its 1280x720 set today.
    assert is_tuning("checkerboard", 67, 1280, 720) and not is_tuning("checkerboard", 67, 1920, 1080)
    t = describe("checkerboard", 7, 1280, 720)
    assert t.startswith("checkerboard tuning set (seed 7, 1280x720)") and "not held out" in t and "min_margin" in t
    assert "evaluation set" in describe("checkerboard", 2026, 1280, 720) and "tuning set" in describe("checkerboard", 2026, 1280, 720)
    assert "its scenes at 1920x1080 before 2026-12-07" in describe("checkerboard", 67, 1280, 720)
    h = describe("checkerboard", 31, 800, 600)
    assert h.startswith("checkerboard held-out set (seed 31, 800x600)") and "tuning set (" not in h
    for r in TUNING_SETS:
        assert r.kind in ("checkerboard", "aprilgrid") and r.why and is_tuning(r.kind, r.seed, *(KEPT_SIZE if r.old_seeds else r.size))
        assert r.size is None or (len(r.size) == 2 and all(isinstance(v, int) for v in r.size))
    with pytest.raises(dataclasses.FrozenInstanceError):
        TUNING_SETS[0].seed = 8
    assert TuningSet("checkerboard", 5, (640, 480), "x", old_seeds=False).marks("checkerboard", 5, 640, 480)
    assert TuningSet("checkerboard", 5, None, "x").marks("checkerboard", 5, 320, 240)


def _tiny(seed: int, width: int, height: int):
    from calib_eval.detection.evaluation import EvalConfig

    return EvalConfig(fovs=[], per_fov=0, n_empty=0, seed=seed, width=width, height=height, conditions=["over-exposed"], per_condition=2)


def test_a_set_off_1280x720_shows_other_scenes_than_the_same_seed_at_another_size(tmp_path):
    """Two frames of one seed at 320x240 and at 320x256, through render_benchmark: the FoV each
    frame drew (180-240 in a condition row) differs. Under the seeds before (the seed alone) the two
    sizes drew the same FoV: the scenes of one set again."""
    from calib_eval.detection.conditions import CONDITIONS
    from calib_eval.detection.evaluation import BENCH_VERSION, _render_cfg, render_benchmark
    from cotrain.render.renderer import render_batch

    a = render_benchmark(_tiny(7, 320, 240), tmp_path / "a", progress=False)["labels"]
    b = render_benchmark(_tiny(7, 320, 256), tmp_path / "b", progress=False)["labels"]
    assert [lab["image"] for lab in a] == [lab["image"] for lab in b]
    assert [lab["fov"] for lab in a] != [lab["fov"] for lab in b]
    old = 7 * 1000 + BENCH_VERSION * 100 + 50 + list(CONDITIONS).index("over-exposed")  # the seed alone
    fovs = []
    for w, h in ((320, 240), (320, 256)):
        rc = _render_cfg((180.0, 240.0), _tiny(7, w, h), ["kb4"], condition="over-exposed")  # frame 0: kb4
        fovs.append(float(render_batch(rc, [0], seed=old)["fov"][0]))
    assert fovs[0] == pytest.approx(fovs[1])


def test_a_1280x720_set_keeps_its_frames():
    """A 1280x720 frame rendered by render_benchmark is the one the seed alone gave (the formula of
    every set before 2026-12-07): the same pixels and labels."""
    import tempfile
    from pathlib import Path

    import cv2

    from calib_eval.detection.evaluation import BENCH_VERSION, EvalConfig, _render_cfg, render_benchmark
    from cotrain.geometry import cameras
    from cotrain.render.renderer import render_batch

    cfg = EvalConfig(fovs=[200], per_fov=1, n_empty=0, seed=7, conditions=[])
    with tempfile.TemporaryDirectory() as d:
        (lab,) = render_benchmark(cfg, Path(d), progress=False)["labels"]
        img = cv2.imread(str(Path(d) / "images" / lab["image"]), cv2.IMREAD_UNCHANGED)
    rc = _render_cfg(200, cfg, [m for m in cameras.MODELS if m != "kb4"])
    ref = render_batch(rc, [0], seed=7 * 1000 + BENCH_VERSION * 100 + 20)
    np.testing.assert_array_equal(img, (ref["image"][0, 0].numpy() * 255).round().astype(np.uint8))
    assert lab["corners"] == ref["corners_raw"][0].tolist()


def test_a_cached_set_of_the_old_frames_is_rendered_again_off_1280x720_only(tmp_path):
    """``load_or_render`` renders a set again whose labels.json lacks the seed scheme at a size off
    1280x720 (its frames are the old ones), and reuses a 1280x720 set without it (the same frames
    under both). The AprilGrid set's cache key likewise."""
    from calib_eval.detection.evaluation import BENCH_VERSION, EvalConfig, _condition_settings, load_or_render
    from cotrain.render.renderer import LABEL_VERSION

    cfg = EvalConfig(fovs=[200], per_fov=1, n_empty=0, seed=3, width=160, height=120, conditions=[])
    meta = load_or_render(cfg, tmp_path, progress=False)
    assert meta["seed_scheme"] == 2
    old = {k: v for k, v in meta.items() if k != "seed_scheme"}
    (tmp_path / "labels.json").write_text(json.dumps(old))
    (tmp_path / "predictions_learned.json").write_text("{}")
    assert load_or_render(cfg, tmp_path, progress=False)["seed_scheme"] == 2  # rendered again
    assert not (tmp_path / "predictions_learned.json").exists()

    kept = EvalConfig(fovs=[200], per_fov=1, n_empty=0, seed=3, conditions=[])  # 1280x720
    stored = {"version": BENCH_VERSION, "label_version": LABEL_VERSION, "config": dataclasses.asdict(kept)}
    stored |= {"conditions": _condition_settings(kept), "labels": ["as cached"]}
    (tmp_path / "k").mkdir()
    (tmp_path / "k" / "labels.json").write_text(json.dumps(stored))
    assert load_or_render(kept, tmp_path / "k", progress=False)["labels"] == ["as cached"]  # reused, not rendered


def test_aprilgrid_frames_depend_on_the_size_too(tmp_path):
    """The AprilGrid set's frames (``tags.render_frame``) of one seed at two sizes off 1280x720 draw
    other FoVs in a condition row; its cache records the seed scheme there."""
    from calib_eval.detection.evaluation import EvalConfig
    from calib_eval.detection.tags import TagEvalConfig, render_frame, render_set
    from cotrain.targets import TargetConfig, make_target

    g = make_target(TargetConfig(kind="aprilgrid"))
    fovs = []
    for w, h in ((320, 240), (320, 256)):
        cfg = TagEvalConfig(seed=2027, width=w, height=h)
        fovs.append(
            [float(render_frame(cfg, EvalConfig(width=w, height=h, target=g.cfg), None, "glare", i)[0]["fov"][0]) for i in range(2)]
        )
    assert fovs[0] != fovs[1]
    cfg = TagEvalConfig(fovs=[200], per_fov=1, n_empty=0, per_condition=0, width=320, height=240)
    render_set(cfg, g, tmp_path)
    assert json.loads((tmp_path / "labels.json").read_text())["key"]["seed_scheme"] == 2


def test_the_independent_renderers_tuning_sets_are_never_reported_as_held_out():
    """Every set FOREIGN_TUNING names is a set the regression keeps, of the independent renderer,
    and the regression marks it tuning; the one it does not name stays reported."""
    from calib_eval.detection.regression import KEPT_SETS
    from calib_eval.detection.sets import FOREIGN_TUNING

    kept = {s.name: s for s in KEPT_SETS}
    assert set(FOREIGN_TUNING) <= set(kept)
    for name in FOREIGN_TUNING:
        assert kept[name].source == "foreign" and kept[name].tuning
    assert not kept["foreign_checkerboard_defocus"].tuning
