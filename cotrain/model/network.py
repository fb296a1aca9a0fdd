"""Multi-stage corner network (paper appendix A-B): U-Net encoder, per-identity heatmaps at 1/4,
rough -> updated -> refined corners, and visibility / learnability / confidence heads.

Identity: every corner slot k has its own heatmap channel H_k at 1/4 resolution. To make identity
cheap to learn on a CPU budget, H_k is factorised into a class-agnostic corner score c(x), a dense
board-coordinate field uv(x) (where on the grid this pixel lies, supervised on every board pixel)
and a per-slot residual r_k(x):

    H_k(x) = c(x) - |uv(x) - g_k|^2 / (2 tau^2) + r_k(x),    g_k = (i_k, j_k) the slot's grid position

so a channel fires where there is a corner *and* the pixel believes it is grid position g_k.
Global context for uv comes from self-attention at 1/16 and pooled 1/32 features.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import torch
import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

from cotrain.geometry.letterbox import CELLS


@dataclass
class ModelConfig:
    input_size: tuple[int, int] = (216, 384)  # processing resolution (H, W); images are resized to it
    widths: list[int] = field(default_factory=lambda: [8, 16, 48, 80, 128, 160])  # full, 1/2, 1/4, 1/8, 1/16, 1/32
    decoder_width: int = 64  # channels of the 1/4 decoder output
    decoder_bottleneck: int = 0  # >0: each decoder stage squeezes to this many channels (1x1 conv) before its 3x3 conv; 0: none
    attention_heads: int = 4  # heads of the self-attention block at 1/16
    tau: float = 0.35  # identity kernel width in grid units (see module docstring)
    slot_embed: int = 32  # learned per-slot embedding size for the point heads
    point_hidden: int = 128  # hidden width of the update / head MLPs
    max_update_px: float = 6.0  # largest correction of the update stage, processing pixels
    max_refine_px: float = 1.5  # largest correction of the refinement stage, processing pixels
    refine_patch: int = 7  # side of the full-resolution patch the refiner sees
    softargmax_window: int = 5  # window (cells) of the local soft-argmax around each peak
    n_corners: int = 54  # corner slots (from the target)
    grid_nx: int = 9  # inner corners along x (from the target)
    grid_ny: int = 6  # inner corners along y (from the target)
    identity: str = "regress"  # "regress": uv regression + Gaussian kernel; "classify": nearest column / row classes


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


def _decoder_stage(cin: int, cout: int, bottleneck: int) -> nn.Sequential:
    """One decoder stage (cin -> cout at the skip's resolution): a 3x3 conv, or, with a
    ``bottleneck`` > 0, a 1x1 conv to that many channels first (the 3x3 convs at 1/4 and 1/8 over
    the concatenated skip and upsampled features are most of the network's time on a CPU)."""
    if bottleneck <= 0:
        return _conv(cin, cout)
    squeeze = nn.Sequential(nn.Conv2d(cin, bottleneck, 1, bias=False), nn.BatchNorm2d(bottleneck), nn.ReLU(inplace=True))
    return nn.Sequential(squeeze, _conv(bottleneck, cout))


class _Block(nn.Sequential):
    def __init__(self, cin: int, cout: int, stride: int):
        super().__init__(_conv(cin, cout, stride), _conv(cout, cout))


class _Attention(nn.Module):
    """One transformer layer over the 1/16 feature map, with a learned 2-D positional bias."""

    def __init__(self, c: int, heads: int):
        super().__init__()
        self.norm1 = nn.LayerNorm(c)
        self.attn = nn.MultiheadAttention(c, heads, batch_first=True)
        self.norm2 = nn.LayerNorm(c)
        self.mlp = nn.Sequential(nn.Linear(c, 2 * c), nn.GELU(), nn.Linear(2 * c, c))
        self.pos = nn.Conv2d(2, c, 1)

    def forward(self, x: Tensor) -> Tensor:
        B, C, H, W = x.shape
        ys = torch.linspace(-1, 1, H, device=x.device, dtype=x.dtype)
        xs = torch.linspace(-1, 1, W, device=x.device, dtype=x.dtype)
        grid = torch.stack(torch.meshgrid(xs, ys, indexing="xy"), 0)[None]
        t = (x + self.pos(grid)).flatten(2).transpose(1, 2)
        h = self.norm1(t)
        t = t + self.attn(h, h, h, need_weights=False)[0]
        t = t + self.mlp(self.norm2(t))
        return t.transpose(1, 2).reshape(B, C, H, W)


def _sample(feat: Tensor, q: Tensor, stride: float) -> Tensor:
    """Bilinear features at processing pixels q (B, N, 2) from a map of the given stride -> (B, N, C)."""
    H, W = feat.shape[-2:]
    x = (q[..., 0] + 0.5) / stride - 0.5
    y = (q[..., 1] + 0.5) / stride - 0.5
    g = torch.stack([2 * (x + 0.5) / W - 1, 2 * (y + 0.5) / H - 1], -1)
    return F.grid_sample(feat, g[:, :, None, :], mode="bilinear", padding_mode="border", align_corners=False)[..., 0].transpose(1, 2)


class CornerNet(nn.Module):
    def __init__(self, cfg: ModelConfig):
        super().__init__()
        self.cfg = cfg
        w = cfg.widths
        self.side = nn.Sequential(_conv(1, w[0]), _conv(w[0], w[0]))  # shallow full-resolution branch
        self.enc1 = _Block(w[0], w[1], 2)
        self.enc2 = _Block(w[1], w[2], 2)
        self.enc3 = _Block(w[2], w[3], 2)
        self.enc4 = _Block(w[3], w[4], 2)
        self.enc5 = _Block(w[4], w[5], 2)
        self.attn = _Attention(w[4], cfg.attention_heads)
        self.ctx = nn.Sequential(nn.Linear(w[5], w[4]), nn.ReLU(inplace=True))
        b = cfg.decoder_bottleneck
        self.dec4 = _decoder_stage(w[4] + w[5], w[4], b)
        self.dec3 = _decoder_stage(w[3] + w[4], w[3], b)
        self.dec2 = _decoder_stage(w[2] + w[3], cfg.decoder_width, b)
        D = cfg.decoder_width
        self.head_corner = nn.Conv2d(D, 1, 1)
        if cfg.identity not in ("regress", "classify"):
            raise ValueError(f"model.identity must be 'regress' or 'classify', not {cfg.identity!r}")
        # classify: logits over the nearest corner column (-1 .. nx) and row (-1 .. ny).
        self.n_cols, self.n_rows = cfg.grid_nx + 2, cfg.grid_ny + 2
        self.head_uv = nn.Conv2d(D, 2 if cfg.identity == "regress" else self.n_cols + self.n_rows, 1)
        self.head_mask = nn.Conv2d(D, 1, 1)
        self.head_residual = nn.Conv2d(D, cfg.n_corners, 1)
        nn.init.zeros_(self.head_residual.weight)
        nn.init.zeros_(self.head_residual.bias)
        nn.init.constant_(self.head_corner.bias, -4.0)
        ij = torch.stack([torch.arange(cfg.n_corners) % cfg.grid_nx, torch.arange(cfg.n_corners) // cfg.grid_nx], -1)
        self.register_buffer("grid_pos", ij.float(), persistent=False)
        self.slot = nn.Embedding(cfg.n_corners, cfg.slot_embed)
        Hd = cfg.point_hidden
        n_in = D + w[3] + w[4] + cfg.slot_embed + 1
        self.update = nn.Sequential(nn.Linear(n_in, Hd), nn.ReLU(inplace=True), nn.Linear(Hd, Hd), nn.ReLU(inplace=True))
        self.update_out = nn.Linear(Hd, 2)
        self.vis_out = nn.Linear(Hd, 1)
        self.learn_out = nn.Linear(Hd, 1)
        P = cfg.refine_patch
        self.refine = nn.Sequential(nn.Linear(w[0] * P * P + Hd, Hd), nn.ReLU(inplace=True), nn.Linear(Hd, Hd), nn.ReLU(inplace=True))
        self.refine_out = nn.Linear(Hd, 2)
        self.conf_out = nn.Linear(Hd, 1)
        for lin in (self.update_out, self.refine_out):
            nn.init.zeros_(lin.weight)
            nn.init.zeros_(lin.bias)
        off = torch.arange(P, dtype=torch.float32) - (P - 1) / 2
        self.register_buffer("patch_offsets", torch.stack(torch.meshgrid(off, off, indexing="xy"), -1).reshape(-1, 2), persistent=False)

    def _soft_argmax(self, heat: Tensor) -> tuple[Tensor, Tensor]:
        """Local soft-argmax around each channel's peak. heat (B, N, h, w) logits -> q (B, N, 2)
        in processing pixels, and the peak logit (B, N)."""
        B, N, h, w = heat.shape
        r = self.cfg.softargmax_window // 2
        flat = heat.flatten(2)
        peak, idx = flat.max(-1)
        py = torch.div(idx, w, rounding_mode="floor")
        px = idx - py * w
        d = torch.arange(-r, r + 1, device=heat.device)
        k = 2 * r + 1
        yy = (py[..., None, None] + d[None, None, :, None]).clamp(0, h - 1).expand(B, N, k, k)
        xx = (px[..., None, None] + d[None, None, None, :]).clamp(0, w - 1).expand(B, N, k, k)
        lin = (yy * w + xx).flatten(2)
        vals = torch.gather(flat, 2, lin)
        p = torch.softmax(vals, -1)
        cx = (p * xx.flatten(2).to(heat.dtype)).sum(-1)
        cy = (p * yy.flatten(2).to(heat.dtype)).sum(-1)
        q = CELLS.to_pixel(torch.stack([cx, cy], -1))  # 1/4 cell centre -> processing pixel
        return q, peak

    def forward(self, image: Tensor) -> dict[str, Tensor]:
        """Run the network on images already at the processing resolution.

        Args:
            image: (B, 1, H, W) grey in [0, 1], H, W = ``cfg.input_size`` (multiples of 32 not needed).
        Returns dict:
            heatmap: (B, N, H/4, W/4) per-slot heatmap logits
            corner_logit: (B, 1, H/4, W/4) class-agnostic corner score
            board_uv: (B, 2, H/4, W/4) predicted board grid coordinates (corner (i, j) at (i, j))
            board_col_logits: (B, nx + 2, H/4, W/4) logits of the nearest corner column -1 .. nx ("classify"; 0 channels otherwise)
            board_row_logits: (B, ny + 2, H/4, W/4) logits of the nearest corner row -1 .. ny ("classify"; 0 channels otherwise)
            board_mask_logit: (B, 1, H/4, W/4) logit of "this cell is on the checker squares"
            corners_rough: (B, N, 2) soft-argmax corners, processing pixels
            corners_updated: (B, N, 2) after the 1/8 and 1/16 feature update
            corners: (B, N, 2) refined corners, processing pixels
            visibility_logit: (B, N); learnability: (B, N) in [0, 1]; confidence_logit: (B, N)
        """
        cfg = self.cfg
        x = image * 2 - 1
        f0 = self.side(x)
        f1 = self.enc1(f0)
        f2 = self.enc2(f1)
        f3 = self.enc3(f2)
        f4 = self.attn(self.enc4(f3))
        f5 = self.enc5(f4)
        f4 = f4 + self.ctx(f5.mean((2, 3)))[..., None, None]
        up = lambda a, b: F.interpolate(a, size=b.shape[-2:], mode="bilinear", align_corners=False)  # noqa: E731
        d4 = self.dec4(torch.cat([f4, up(f5, f4)], 1))
        d3 = self.dec3(torch.cat([f3, up(d4, f3)], 1))
        d2 = self.dec2(torch.cat([f2, up(d3, f2)], 1))

        corner = self.head_corner(d2)
        mask = self.head_mask(d2)
        if cfg.identity == "regress":
            uv = self.head_uv(d2)
            col_logits, row_logits = uv[:, :0], uv[:, :0]
            dist2 = ((uv[:, None] - self.grid_pos[None, :, :, None, None]) ** 2).sum(2)  # (B, N, h, w)
            ident = -dist2 / (2 * cfg.tau**2)
        else:
            uv_logits = self.head_uv(d2)
            col_logits, row_logits = uv_logits[:, : self.n_cols], uv_logits[:, self.n_cols :]
            lu = F.log_softmax(col_logits, 1)  # (B, nx + 2, h, w)
            lv = F.log_softmax(row_logits, 1)
            gi = self.grid_pos[:, 0].long() + 1
            gj = self.grid_pos[:, 1].long() + 1
            ident = lu[:, gi] + lv[:, gj]  # log p(column i_k) + log p(row j_k), (B, N, h, w)
            cols = torch.arange(-1, cfg.grid_nx + 1, dtype=d2.dtype, device=d2.device)
            rows = torch.arange(-1, cfg.grid_ny + 1, dtype=d2.dtype, device=d2.device)
            uv = torch.stack([(lu.exp() * cols[None, :, None, None]).sum(1), (lv.exp() * rows[None, :, None, None]).sum(1)], 1)
        heat = corner + ident + self.head_residual(d2)

        q_rough, peak = self._soft_argmax(heat)
        B, N = q_rough.shape[:2]
        slot = self.slot.weight[None].expand(B, -1, -1)
        qd = q_rough.detach()
        h = torch.cat([_sample(d2, qd, 4), _sample(d3, qd, 8), _sample(d4, qd, 16), slot, peak.detach()[..., None]], -1)
        h = self.update(h)
        q_upd = q_rough + cfg.max_update_px * torch.tanh(self.update_out(h) / cfg.max_update_px)
        vis = self.vis_out(h)[..., 0]
        learn = torch.sigmoid(self.learn_out(h)[..., 0])

        P = cfg.refine_patch
        pts = q_upd.detach()[:, :, None, :] + self.patch_offsets[None, None]  # (B, N, P*P, 2)
        patch = _sample(f0, pts.reshape(B, N * P * P, 2), 1).reshape(B, N, P * P * f0.shape[1])
        g = self.refine(torch.cat([patch, h], -1))
        q_ref = q_upd + cfg.max_refine_px * torch.tanh(self.refine_out(g) / cfg.max_refine_px)
        conf = self.conf_out(g)[..., 0]
        return {
            "heatmap": heat,
            "corner_logit": corner,
            "board_uv": uv,
            "board_col_logits": col_logits,
            "board_row_logits": row_logits,
            "board_mask_logit": mask,
            "corners_rough": q_rough,
            "corners_updated": q_upd,
            "corners": q_ref,
            "visibility_logit": vis,
            "learnability": learn,
            "confidence_logit": conf,
        }
