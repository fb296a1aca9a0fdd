"""The paper's training objective (appendix A-C), every term weighted in the config.

L = l_h+ L_h+ + l_h- L_h- + l_e L_e + sum_s l_s L_s (s = rough, updated, refined)
    + sum_a l_a L_a (a = visibility, learnability, confidence) + auxiliary board and corner-score terms.

Shapes: N corner slots, (h, w) the 1/4 heatmap grid, coordinates in processing pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from cotrain.geometry.letterbox import CELLS


@dataclass
class LossConfig:
    heat_pos: float = 1.0  # lambda_h+: heatmap BCE towards the Gaussian on supervised slots
    heat_neg: float = 1.0  # lambda_h-: heatmap BCE towards 0 on slots that are not visible
    exclusion: float = 0.5  # lambda_e: channel k must not fire at other visible corners j
    rough: float = 0.05  # lambda_r: rough (soft-argmax) coordinates
    updated: float = 0.1  # lambda_u: coordinates after the 1/8 and 1/16 update
    refined: float = 0.2  # lambda_f: refined coordinates
    visibility: float = 0.5  # lambda_v
    learnability: float = 0.5  # lambda_l
    confidence: float = 0.2  # lambda_c
    board_uv: float = 0.5  # auxiliary: dense board coordinates on board cells (regression, or column/row classification)
    board_mask: float = 0.5  # auxiliary: board mask BCE
    corner: float = 1.0  # auxiliary: class-agnostic corner score towards max_k G_k (balanced BCE); feeds the detector's grid pass
    heat_sigma_cells: float = 0.75  # sigma of the target Gaussian G_i, in 1/4 cells
    huber_rough_px: float = 2.0  # delta of the rough stage's Huber loss (processing px)
    huber_updated_px: float = 1.0  # delta of the updated stage's Huber loss
    huber_refined_px: float = 0.25  # delta of the refined stage's Huber loss
    conf_sigma_px: float = 0.5  # sigma of the confidence target exp(-e^2 / 2 sigma^2)
    distill_dense: float = 0.0  # with a teacher (train.teacher): its dense maps (corner score, board mask, column / row) as soft targets


def gaussian_targets(corners: Tensor, h: int, w: int, sigma: float) -> Tensor:
    """G_i: (B, N, h, w) Gaussians at corners (B, N, 2) given in processing pixels."""
    c = CELLS.to_cell(corners)  # processing pixel -> 1/4 cell coordinates
    ys = torch.arange(h, dtype=corners.dtype, device=corners.device)
    xs = torch.arange(w, dtype=corners.dtype, device=corners.device)
    gx = torch.exp(-((xs[None, None] - c[..., :1]) ** 2) / (2 * sigma**2))  # (B, N, w)
    gy = torch.exp(-((ys[None, None] - c[..., 1:]) ** 2) / (2 * sigma**2))  # (B, N, h)
    return gy[..., :, None] * gx[..., None, :]


def sample_logits(heat: Tensor, points: Tensor) -> Tensor:
    """H_k(p_j) for every channel k and point j: heat (B, N, h, w), points (B, M, 2) processing
    pixels -> (B, N, M), bilinear."""
    h, w = heat.shape[-2:]
    c = CELLS.to_cell(points)
    g = torch.stack([(2 * c[..., 0] + 1) / w - 1, (2 * c[..., 1] + 1) / h - 1], -1)
    return F.grid_sample(heat, g[:, None], mode="bilinear", padding_mode="border", align_corners=False)[:, :, 0]


def _weighted_mean(x: Tensor, w: Tensor) -> Tensor:
    return (x * w).sum() / w.sum().clamp_min(1e-6)


def _huber_px(pred: Tensor, gt: Tensor, delta: float) -> Tensor:
    """Huber of the Euclidean pixel error, (B, N)."""
    e = (pred - gt).norm(dim=-1)
    return torch.where(e < delta, 0.5 * e * e / delta, e - 0.5 * delta)


def compute_losses(out: dict[str, Tensor], batch: dict[str, Tensor], cfg: LossConfig) -> dict[str, Tensor]:
    """Every loss term, unweighted, plus ``total`` (weighted sum).

    ``batch`` needs (processing resolution): corners (B, N, 2), visible (B, N) bool,
    learnability (B, N), board_mask (B, 1, H, W), board_uv (B, 2, H, W); and may carry
    ``teacher``, a teacher network's outputs on the same images (:func:`distillation_loss`).
    Returns dict of scalars: heat_pos, heat_neg, exclusion, rough, updated, refined, visibility,
    learnability, confidence, board_uv, board_mask, corner (and distill_dense with a teacher),
    total; and ``refined_error`` (B, N) px.
    """
    heat = out["heatmap"]
    B, N, h, w = heat.shape
    m_vis = batch["visible"].to(heat.dtype)
    w_sup = m_vis * batch["learnability"].to(heat.dtype)
    gt = batch["corners"].to(heat.dtype)

    # Heatmap: positive channels towards G_i (positive and negative parts of the BCE balanced),
    # channels of invisible slots towards 0 everywhere.
    G = gaussian_targets(gt, h, w, cfg.heat_sigma_cells)
    logp = F.logsigmoid(heat)
    log1mp = F.logsigmoid(-heat)
    pos = -(G * logp).sum((2, 3)) / G.sum((2, 3)).clamp_min(1e-6)
    neg = -((1 - G) * log1mp).sum((2, 3)) / (1 - G).sum((2, 3)).clamp_min(1e-6)
    L_hpos = _weighted_mean(pos + neg, w_sup)
    L_hneg = _weighted_mean(-log1mp.mean((2, 3)), 1 - m_vis)

    # Exclusion: channel k at visible corner j != k -> 0.
    Hkj = sample_logits(heat, gt)  # (B, N_k, N_j)
    pair = m_vis[:, :, None] * m_vis[:, None, :] * (1 - torch.eye(N, dtype=heat.dtype, device=heat.device))
    L_e = _weighted_mean(F.binary_cross_entropy_with_logits(Hkj, torch.zeros_like(Hkj), reduction="none"), pair)

    # Coordinates, stage-specific robust losses.
    L_r = _weighted_mean(_huber_px(out["corners_rough"], gt, cfg.huber_rough_px), w_sup)
    L_u = _weighted_mean(_huber_px(out["corners_updated"], gt, cfg.huber_updated_px), m_vis)
    L_f = _weighted_mean(_huber_px(out["corners"], gt, cfg.huber_refined_px), m_vis)

    # Auxiliary heads.
    L_v = F.binary_cross_entropy_with_logits(out["visibility_logit"], m_vis)
    L_l = _weighted_mean((out["learnability"] - batch["learnability"].to(heat.dtype)).abs(), m_vis)
    err = (out["corners"].detach() - gt).norm(dim=-1)
    conf_t = m_vis * torch.exp(-(err**2) / (2 * cfg.conf_sigma_px**2))
    L_c = F.binary_cross_entropy_with_logits(out["confidence_logit"], conf_t)

    # Dense board terms at 1/4 resolution.
    mask4 = F.avg_pool2d(batch["board_mask"].to(heat.dtype), 4)[..., :h, :w]
    uv4 = F.avg_pool2d(batch["board_uv"].to(heat.dtype) * batch["board_mask"], 4)[..., :h, :w] / mask4.clamp_min(1e-6)
    on = (mask4 > 0.99).to(heat.dtype)
    cols, rows = out.get("board_col_logits"), out.get("board_row_logits")
    if cols is not None and cols.shape[1] > 0:
        # Classification of the nearest corner column (-1 .. nx) and row (-1 .. ny).
        ci = (uv4[:, 0].round() + 1).clamp(0, cols.shape[1] - 1).long()
        cj = (uv4[:, 1].round() + 1).clamp(0, rows.shape[1] - 1).long()
        ce = F.cross_entropy(cols, ci, reduction="none") + F.cross_entropy(rows, cj, reduction="none")
        L_uv = _weighted_mean(ce[:, None], on)
    else:
        L_uv = _weighted_mean(F.smooth_l1_loss(out["board_uv"], uv4, reduction="none").sum(1, keepdim=True), on)
    L_mask = F.binary_cross_entropy_with_logits(out["board_mask_logit"], mask4)

    # Class-agnostic corner score: every visible corner, whatever its id (balanced like L_h+).
    Gmax = (G * m_vis[..., None, None]).amax(1, keepdim=True)  # (B, 1, h, w)
    cl = out["corner_logit"]
    c_pos = -(Gmax * F.logsigmoid(cl)).sum((1, 2, 3)) / Gmax.sum((1, 2, 3)).clamp_min(1e-6)
    c_neg = -((1 - Gmax) * F.logsigmoid(-cl)).sum((1, 2, 3)) / (1 - Gmax).sum((1, 2, 3)).clamp_min(1e-6)
    L_corner = (c_pos + c_neg).mean()

    terms = {
        "heat_pos": L_hpos,
        "heat_neg": L_hneg,
        "exclusion": L_e,
        "rough": L_r,
        "updated": L_u,
        "refined": L_f,
        "visibility": L_v,
        "learnability": L_l,
        "confidence": L_c,
        "board_uv": L_uv,
        "board_mask": L_mask,
        "corner": L_corner,
    }
    total = sum(getattr(cfg, k) * v for k, v in terms.items())
    if "teacher" in batch:
        terms["distill_dense"] = distillation_loss(out, batch["teacher"])
        total = total + cfg.distill_dense * terms["distill_dense"]
    return {**terms, "total": total, "refined_error": err}


def distillation_loss(out: dict[str, Tensor], teacher: dict[str, Tensor]) -> Tensor:
    """The student's dense maps against a teacher's (the outputs the detector's grid pass reads):
    BCE of the corner score and the board mask towards the teacher's probabilities, and
    KL(teacher || student) of the column and the row classes, per 1/4 cell, averaged. Zero when
    the two agree everywhere. ``out`` and ``teacher``: :class:`cotrain.model.network.CornerNet`
    outputs (corner_logit, board_mask_logit (B, 1, h, w); board_col_logits (B, nx + 2, h, w),
    board_row_logits (B, ny + 2, h, w))."""

    def bce(name: str) -> Tensor:
        p = torch.sigmoid(teacher[name])
        return F.binary_cross_entropy_with_logits(out[name], p) - F.binary_cross_entropy_with_logits(teacher[name], p)

    def kl(name: str) -> Tensor:
        lt = F.log_softmax(teacher[name], 1)
        return (lt.exp() * (lt - F.log_softmax(out[name], 1))).sum(1).mean()

    return bce("corner_logit") + bce("board_mask_logit") + kl("board_col_logits") + kl("board_row_logits")
