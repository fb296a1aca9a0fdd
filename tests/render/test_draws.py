"""The batched renderer's random streams and frames against the per-sample renderer it replaced:
torch's generator (the independent reference for the streams) and frames that renderer drew."""

import numpy as np
import pytest
import torch

from calib_eval.benchmark.timing import count_render_ops
from cotrain.render.draws import SampleDraws, box_muller, sample_draws
from cotrain.render.renderer import RenderConfig, render_batch
from cotrain.targets import TargetConfig
from tests.paths import ROOT

FIXTURE = ROOT / "tests" / "data" / "per_sample_renderer.npz"  # drawn by the renderer of commit 924f47e (draws one sample at a time)


@pytest.mark.parametrize("seed", [0, 12_345, 2**40 + 17, 2**63 - 2])
def test_a_stream_replays_torchs_generator_number_for_number(seed):
    """Scalars, float32 arrays, normals (whole blocks of 16 and a tail) and category draws, in an
    interleaved order, are torch.Generator's under the same seed."""
    g = torch.Generator().manual_seed(seed)
    d = SampleDraws(seed)
    weights = [0.4, 0.2, 0.2, 0.2]
    for n in (16, 40, 96, 1000):
        assert d.uniform() == float(torch.rand((), generator=g, dtype=torch.float64))
        assert d.uniform(-3.0, 5.0) == -3.0 + 8.0 * float(torch.rand((), generator=g, dtype=torch.float64))
        np.testing.assert_array_equal(d.uniform32(3, 7), torch.rand(3, 7, generator=g).numpy())
        want = torch.randn(n, generator=g)
        np.testing.assert_allclose(box_muller(torch.from_numpy(d.normal_uniforms(n)), n).numpy(), want.numpy(), atol=2e-6)
        assert d.choice(weights) == int(torch.multinomial(torch.tensor(weights, dtype=torch.float64), 1, generator=g))
    assert d.initial_seed() == g.initial_seed()


def test_sample_streams_do_not_depend_on_the_batch():
    a, b = sample_draws(9, 5), sample_draws(9, 5)
    assert [a.uniform() for _ in range(5)] == [b.uniform() for _ in range(5)]
    assert sample_draws(9, 5).uniform() != sample_draws(9, 6).uniform()


def test_the_batched_renderer_draws_the_per_sample_renderers_frames():
    """Every effect on (distractors, occluders, glare, motion blur, JPEG, supersampling; an
    AprilGrid too): the frames and labels the per-sample renderer drew, within float rounding."""
    ref = np.load(FIXTURE)
    hard = RenderConfig(height=48, width=80, p_distractor=1.0, p_occluder=0.7, p_glare=0.5, p_motion=0.7, p_jpeg=0.5, supersample=2)
    april = RenderConfig(height=48, width=80, target=TargetConfig(kind="aprilgrid"))
    for name, cfg, idx in (("hard", hard, [0, 3, 5, 8, 13, 21]), ("april", april, [2, 4])):
        b = render_batch(cfg, idx, seed=62)
        np.testing.assert_array_equal(b["visible"].numpy(), ref[f"{name}_visible"])
        for key in ("image", "corners_raw", "learnability", "square_px", "board_mask", "board_uv"):
            np.testing.assert_allclose(b[key].numpy(), ref[f"{name}_{key}"], atol=1e-5, err_msg=f"{name} {key}")


def test_rendering_a_batch_costs_operator_calls_by_the_batch_not_by_the_sample():
    """64 samples issue at most 1.5x the operator calls of 8 (the per-sample renderer: 6.5x)."""
    cfg = RenderConfig(height=36, width=64, p_distractor=1.0, p_occluder=0.5, p_motion=0.5, p_jpeg=0.5)
    small, large = count_render_ops(cfg, 8), count_render_ops(cfg, 64)
    assert large <= 1.5 * small, (small, large)
