"""The model's named outputs (cotrain.model.outputs): the dense maps from the int8 graph's logits."""

import numpy as np
import torch

from cotrain.model.outputs import DENSE_OUTPUTS, LOGITS, dense_maps, log_softmax_channels


def test_log_softmax_over_the_channel_axis_is_torchs():
    """Against torch.log_softmax over dim -3, for a batch of maps, large logits included (the
    largest is subtracted first: no overflow); each cell's probabilities sum to one."""
    x = np.random.default_rng(0).normal(0, 30, (2, 11, 5, 7)).astype(np.float32)
    x[0, 3, 1, 1] = 500.0
    got = log_softmax_channels(x)
    np.testing.assert_allclose(got, torch.log_softmax(torch.from_numpy(x), dim=-3).numpy(), atol=1e-5)
    np.testing.assert_allclose(np.exp(got).sum(-3), 1.0, atol=1e-5)
    assert got.dtype == np.float32 and np.isfinite(got).all()


def test_dense_maps_take_the_log_probabilities_as_given_or_from_their_logits():
    rng = np.random.default_rng(1)
    maps = {"corner_prob": rng.random((1, 1, 4, 6)), "mask_prob": rng.random((1, 1, 4, 6))}
    logits = {LOGITS["col_logp"]: rng.normal(size=(1, 11, 4, 6)), LOGITS["row_logp"]: rng.normal(size=(1, 8, 4, 6))}
    got = dense_maps({**maps, **logits})
    assert tuple(got) == DENSE_OUTPUTS
    np.testing.assert_allclose(got["col_logp"], log_softmax_channels(logits["col_logits"]))
    given = {**maps, "col_logp": np.zeros((1, 11, 4, 6)), "row_logp": np.ones((1, 8, 4, 6))}
    assert dense_maps(given)["row_logp"] is given["row_logp"]
