"""``make bench``: every benchmark the docs quote, printed as medians of several runs."""

from __future__ import annotations

import json
import sys
from pathlib import Path

from calib_eval.bench import bench_calibration
from cotrain.bench import bench_render, bench_render_vs_step
from cotrain.renderer import RenderConfig


def main() -> int:
    results = {
        "render_384x216": bench_render(RenderConfig(), batch=8, repeats=5),
        "render_1280x720": bench_render(RenderConfig(height=720, width=1280), batch=4, repeats=3),
        "render_vs_train_step": bench_render_vs_step(),
        "calibration": bench_calibration(),
    }
    out = Path("report") / "bench.json"
    out.parent.mkdir(exist_ok=True)
    out.write_text(json.dumps(results, indent=1, default=str))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
