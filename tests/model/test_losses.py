"""Each loss term against a value computed by hand on small tensors."""

import math

import pytest
import torch

from cotrain.model.losses import LossConfig, compute_losses, gaussian_targets, sample_logits


def _small_case():
    B, N, h, w = 1, 2, 4, 4
    heat = torch.full((B, N, h, w), -2.0)
    out = {
        "heatmap": heat,
        "corners_rough": torch.tensor([[[5.5, 5.5], [9.5, 5.5]]]),
        "corners_updated": torch.tensor([[[5.5, 6.5], [9.5, 5.5]]]),
        "corners": torch.tensor([[[5.5, 5.5], [9.5, 5.5]]]),
        "visibility_logit": torch.tensor([[0.0, 0.0]]),
        "learnability": torch.tensor([[0.5, 0.5]]),
        "confidence_logit": torch.tensor([[0.0, 0.0]]),
        "board_uv": torch.zeros(B, 2, h, w),
        "board_mask_logit": torch.zeros(B, 1, h, w),
        "corner_logit": torch.full((B, 1, h, w), 1.0),
    }
    batch = {
        "corners": torch.tensor([[[5.5, 5.5], [0.0, 0.0]]]),  # corner 0 at cell (1, 1)
        "visible": torch.tensor([[True, False]]),
        "learnability": torch.tensor([[1.0, 0.0]]),
        "board_mask": torch.ones(B, 1, 16, 16),
        "board_uv": torch.ones(B, 2, 16, 16),
    }
    return out, batch


def test_terms_match_hand_values():
    out, batch = _small_case()
    cfg = LossConfig()
    L = compute_losses(out, batch, cfg)
    sp = lambda x: math.log1p(math.exp(x))  # softplus  # noqa: E731
    # heat_neg: channel 1 (not visible) towards 0 everywhere: BCE(-2, 0) = softplus(-2).
    assert L["heat_neg"].item() == pytest.approx(sp(-2.0), rel=1e-5)
    # heat_pos: constant logits -> positive part softplus(2), negative part softplus(-2).
    assert L["heat_pos"].item() == pytest.approx(sp(2.0) + sp(-2.0), rel=1e-5)
    # rough: exact -> 0; updated: 1 px off with Huber delta 1 -> 0.5; refined exact -> 0.
    assert L["rough"].item() == pytest.approx(0.0, abs=1e-6)
    assert L["updated"].item() == pytest.approx(0.5, rel=1e-6)
    assert L["refined"].item() == pytest.approx(0.0, abs=1e-6)
    # visibility: logits 0 -> log 2; learnability: |0.5 - 1| on the visible slot.
    assert L["visibility"].item() == pytest.approx(math.log(2), rel=1e-6)
    assert L["learnability"].item() == pytest.approx(0.5, rel=1e-6)
    # confidence: target exp(0) = 1 for slot 0, 0 for slot 1; logits 0 -> log 2 either way.
    assert L["confidence"].item() == pytest.approx(math.log(2), rel=1e-6)
    # board: uv smooth-L1 of |0 - 1| on two channels = 2 * 0.5; mask BCE(0, 1) = log 2.
    assert L["board_uv"].item() == pytest.approx(1.0, rel=1e-6)
    assert L["board_mask"].item() == pytest.approx(math.log(2), rel=1e-6)
    # exclusion: only one visible corner -> no pairs -> 0.
    assert L["exclusion"].item() == pytest.approx(0.0, abs=1e-9)
    # corner score: constant logit 1 -> positive part softplus(-1), negative part softplus(1).
    assert L["corner"].item() == pytest.approx(sp(-1.0) + sp(1.0), rel=1e-5)


def test_total_is_the_weighted_sum_of_the_hand_values():
    """``total`` on the small case, with weights chosen here (not the recipe's), against the hand
    values of each term; then one weight at a time, and all weights off."""
    out, batch = _small_case()
    sp = lambda x: math.log1p(math.exp(x))  # softplus  # noqa: E731
    ln2 = math.log(2)
    hand = {  # the values of test_terms_match_hand_values
        "heat_pos": sp(2.0) + sp(-2.0),
        "heat_neg": sp(-2.0),
        "exclusion": 0.0,
        "rough": 0.0,
        "updated": 0.5,
        "refined": 0.0,
        "visibility": ln2,
        "learnability": 0.5,
        "confidence": ln2,
        "board_uv": 1.0,
        "board_mask": ln2,
        "corner": sp(-1.0) + sp(1.0),
    }
    weights = dict(
        heat_pos=0.7,
        heat_neg=1.3,
        exclusion=2.0,
        rough=3.0,
        updated=0.25,
        refined=5.0,
        visibility=0.4,
        learnability=2.5,
        confidence=0.1,
        board_uv=0.3,
        board_mask=1.5,
        corner=0.05,
    )
    # 0.7 (s(2) + s(-2)) + 1.3 s(-2) + 0.25 * 0.5 + 0.4 ln2 + 2.5 * 0.5 + 0.1 ln2 + 0.3 + 1.5 ln2 + 0.05 (s(-1) + s(1))
    expected = (
        0.7 * (sp(2.0) + sp(-2.0)) + 1.3 * sp(-2.0) + 0.125 + 0.4 * ln2 + 1.25 + 0.1 * ln2 + 0.3 + 1.5 * ln2 + 0.05 * (sp(-1.0) + sp(1.0))
    )
    assert expected == pytest.approx(4.8853, abs=1e-4)  # the number itself, worked by hand
    total = compute_losses(out, batch, LossConfig(**weights))["total"]
    assert total.item() == pytest.approx(expected, rel=1e-5)
    # Raising one weight by 2 raises the total by twice that term (terms with value 0 leave it alone).
    for k, v in hand.items():
        bumped = compute_losses(out, batch, LossConfig(**{**weights, k: weights[k] + 2.0}))["total"].item()
        assert bumped - total.item() == pytest.approx(2.0 * v, abs=1e-5), k
    # Only one term weighted: the total is that term.
    only = compute_losses(out, batch, LossConfig(**{k: 0.0 for k in weights} | {"updated": 1.0}))["total"].item()
    assert only == pytest.approx(0.5, rel=1e-6)
    assert compute_losses(out, batch, LossConfig(**{k: 0.0 for k in weights}))["total"].item() == 0.0


def test_gaussian_target_peaks_at_corner():
    G = gaussian_targets(torch.tensor([[[5.5, 9.5]]]), 6, 6, 0.75)
    assert G[0, 0].argmax().item() == 2 * 6 + 1  # cell (x=1, y=2)
    assert G.max().item() == pytest.approx(1.0)


def test_exclusion_penalises_other_corners_only():
    B, N, h, w = 1, 2, 8, 8
    corners = torch.tensor([[[5.5, 5.5], [17.5, 17.5]]])  # cells (1, 1) and (4, 4)
    batch = {
        "corners": corners,
        "visible": torch.tensor([[True, True]]),
        "learnability": torch.ones(1, 2),
        "board_mask": torch.zeros(1, 1, 32, 32),
        "board_uv": torch.zeros(1, 2, 32, 32),
    }
    base = {
        "corners_rough": corners,
        "corners_updated": corners,
        "corners": corners,
        "visibility_logit": torch.zeros(1, 2),
        "learnability": torch.ones(1, 2),
        "confidence_logit": torch.zeros(1, 2),
        "board_uv": torch.zeros(1, 2, h, w),
        "board_mask_logit": torch.zeros(1, 1, h, w),
        "corner_logit": torch.zeros(1, 1, h, w),
    }
    own = torch.full((B, N, h, w), -6.0)
    own[0, 0, 1, 1] = 6.0  # channel 0 fires at its own corner
    wrong = torch.full((B, N, h, w), -6.0)
    wrong[0, 0, 4, 4] = 6.0  # channel 0 fires at corner 1's location
    e_own = compute_losses({**base, "heatmap": own}, batch, LossConfig())["exclusion"].item()
    e_wrong = compute_losses({**base, "heatmap": wrong}, batch, LossConfig())["exclusion"].item()
    assert e_own < 0.01 and e_wrong > 1.0
    H = sample_logits(wrong, corners)
    assert H[0, 0, 1].item() == pytest.approx(6.0) and H[0, 0, 0].item() == pytest.approx(-6.0)


def test_corner_term_rewards_any_visible_corner():
    """The class-agnostic score is low only when it fires at every visible corner, whatever its id."""
    out, batch = _small_case()
    batch["visible"] = torch.tensor([[True, True]])
    batch["corners"] = torch.tensor([[[5.5, 5.5], [13.5, 13.5]]])  # cells (1, 1) and (3, 3)
    cfg = LossConfig()
    both = torch.full((1, 1, 4, 4), -6.0)
    both[0, 0, 1, 1] = both[0, 0, 3, 3] = 6.0
    one = torch.full((1, 1, 4, 4), -6.0)
    one[0, 0, 1, 1] = 6.0
    out["corner_logit"] = both
    l_both = compute_losses(out, batch, cfg)["corner"].item()
    out["corner_logit"] = one
    l_one = compute_losses(out, batch, cfg)["corner"].item()
    assert l_both < l_one - 0.5  # measured 3.71 vs 4.86


def test_distillation_is_zero_at_the_teacher_and_pulls_towards_it():
    """distill_dense: zero when the student's dense maps are the teacher's, positive otherwise, and
    its gradient moves the student's maps towards the teacher's."""
    from cotrain.model.losses import distillation_loss

    g = torch.Generator().manual_seed(0)

    def maps():
        return {
            "corner_logit": torch.randn(2, 1, 5, 7, generator=g),
            "board_mask_logit": torch.randn(2, 1, 5, 7, generator=g),
            "board_col_logits": 3 * torch.randn(2, 11, 5, 7, generator=g),
            "board_row_logits": 3 * torch.randn(2, 8, 5, 7, generator=g),
        }

    teacher, student = maps(), maps()
    assert abs(float(distillation_loss(teacher, teacher))) < 1e-5
    for v in student.values():
        v.requires_grad_(True)
    loss = distillation_loss(student, teacher)
    assert float(loss.detach()) > 0.5
    loss.backward()
    with torch.no_grad():
        stepped = {k: v - 0.5 * v.grad for k, v in student.items()}
    assert float(distillation_loss(stepped, teacher)) < float(loss.detach())
