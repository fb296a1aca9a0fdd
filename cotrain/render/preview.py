"""``cotrain render-preview``: a grid of rendered samples with their labelled corners drawn."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from cotrain.render.renderer import RenderConfig, render_batch


def draw_sample(
    image: np.ndarray, corners: np.ndarray, visible: np.ndarray, learn: np.ndarray | None = None, ids_every: int = 9
) -> np.ndarray:
    """Grey float image (H, W) + corners (N, 2) -> BGR uint8 with corners marked.

    Green: visible (brighter = more learnable); red cross: labelled but not visible (if in frame).
    Every ``ids_every``-th visible id is written.
    """
    im = cv2.cvtColor((np.clip(image, 0, 1) * 255).astype(np.uint8), cv2.COLOR_GRAY2BGR)
    h, w = image.shape
    for k, (x, y) in enumerate(corners):
        if not np.isfinite([x, y]).all() or not (0 <= x < w and 0 <= y < h):
            continue
        p = (int(round(x)), int(round(y)))
        if visible[k]:
            g = 255 if learn is None else int(100 + 155 * float(learn[k]))
            cv2.circle(im, p, 2, (0, g, 0), -1, cv2.LINE_AA)
            if k % ids_every == 0:
                cv2.putText(im, str(k), (p[0] + 3, p[1] - 3), cv2.FONT_HERSHEY_SIMPLEX, 0.3, (0, 255, 255), 1, cv2.LINE_AA)
        else:
            cv2.drawMarker(im, p, (0, 0, 255), cv2.MARKER_CROSS, 4, 1)
    return im


def render_preview(cfg: RenderConfig, n: int, out: str | Path, seed: int = 0) -> Path:
    """Render ``n`` samples and write them as one grid image to ``out``."""
    batch = render_batch(cfg, list(range(n)), seed=seed)
    tiles = [
        draw_sample(
            batch["image"][b, 0].numpy(), batch["corners_raw"][b].numpy(), batch["visible"][b].numpy(), batch["learnability"][b].numpy()
        )
        for b in range(n)
    ]
    cols = int(np.ceil(np.sqrt(n)))
    rows = int(np.ceil(n / cols))
    blank = np.zeros_like(tiles[0])
    tiles += [blank] * (rows * cols - n)
    grid = np.concatenate([np.concatenate(tiles[r * cols : (r + 1) * cols], 1) for r in range(rows)], 0)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    if not cv2.imwrite(str(out), grid):
        raise OSError(f"{out}: could not write the image")
    return out
