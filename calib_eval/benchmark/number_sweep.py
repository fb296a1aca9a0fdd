"""Which of the detector's tuned numbers change its output: each one halved and doubled, alone.

    python -m calib_eval.benchmark.number_sweep checkerboard|aprilgrid --json OUT.json
        [--sets DIR] [--every 8] [--md OUT.md]

Every numeric field of the target's settings (``GridConfig`` for the checkerboard, with the
``CompletionConfig`` defaults its completion is built from; ``TagConfig`` with its ``grid`` and
``complete`` for the AprilGrid) is set to half and to twice its value (an int to its rounded half,
or one less where that rounds back, and to its double; zeros and infinities, which switch a rule
off, are left out), the detector is run on fixed tuning frames, and the frames whose ids or
positions (to 1e-4 px) differ from the shipped settings' are counted, with the change in corners
reported. A number that changes no frame either way is one the design does not lean on there:
a candidate for deletion (a rule that buys nothing) or for derivation from another (a size that
only has to be large enough), to be confirmed on every kept set
(:mod:`calib_eval.detection.regression`). The frames, tuning sets only
(:data:`calib_eval.detection.sets.TUNING`):

- checkerboard: every ``every``-th frame, by file name, of the evaluation set and of seed 7 at
  1280x720 (as the regression renders them into ``sets``), the network run once per frame;
- aprilgrid: every ``every``-th frame, by file name, of the AprilGrid evaluation set's FoV rows that
  ``make bench`` times (seed 2027, 1280x720, 50 frames per FoV, rendered into ``report/``).

The checkerboard's completion settings are a ``CompletionConfig`` that the grid pass builds
itself (:func:`cotrain.detect.grid_pass.grid_completion`, a few fields from ``GridConfig``, the rest
defaults); its defaults are swept by standing in that class, for the run, with one whose default
is the swept value. The run is resumable: each number's row is written to ``--json`` as it is
done. docs/results/number_sweep.md is its write-up.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import sys
from collections.abc import Callable, Iterator
from pathlib import Path

import cv2
import numpy as np

from cotrain.detect import grid_pass
from cotrain.detect.buffers import keep_image_buffers
from cotrain.detect.detector import Detector
from cotrain.detect.grid_config import GridConfig
from cotrain.detect.print_model import CompletionConfig
from cotrain.detect.tag_config import TagConfig
from cotrain.detect.tag_pass import tag_pass
from cotrain.targets import TargetConfig, make_target

CHECKERBOARD_SETS = ("evaluation_2026_1280x720", "seed7_1280x720")  # both tuning sets (calib_eval.detection.sets)


def numeric_fields(cfg, prefix: str = "") -> Iterator[tuple[str, int | float]]:
    """(dotted name, value) of every int or float field of the dataclass ``cfg``, nested ones included (bools are not numbers)."""
    for f in dataclasses.fields(cfg):
        v = getattr(cfg, f.name)
        if dataclasses.is_dataclass(v):
            yield from numeric_fields(v, prefix + f.name + ".")
        elif isinstance(v, (int, float)) and not isinstance(v, bool):
            yield prefix + f.name, v


def perturbed(v: int | float) -> list[int | float]:
    """Half and twice ``v`` (see the module's docstring); none for 0 or an infinity."""
    if v == 0 or not math.isfinite(v):
        return []
    if isinstance(v, int):
        half = round(v / 2)
        return [half if half != v else v - 1, 2 * v]
    return [v / 2, v * 2]


def with_field(cfg, name: str, value):
    """``cfg`` with its (dotted) field ``name`` set to ``value``."""
    head, _, rest = name.partition(".")
    return dataclasses.replace(cfg, **{head: with_field(getattr(cfg, head), rest, value) if rest else value})


Outputs = list[tuple[np.ndarray, np.ndarray]]


def checkerboard_runner(sets: Path, every: int) -> tuple[list[str], Callable[[str | None, object], Outputs], int]:
    """The checkerboard's numbers, a function (name, value) -> outputs per frame (name None: shipped), and the frames' count."""
    paths = [p for s in CHECKERBOARD_SETS for p in sorted((sets / s / "images").glob("*.png"))[::every]]
    if not paths:
        raise SystemExit(f"number_sweep: no frames under {sets} (python -m calib_eval.detection.regression --sets {sets} renders them)")
    det = Detector()
    pending = [det.network(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in paths]
    names = [f"grid.{k}" for k, _ in numeric_fields(GridConfig())] + [f"complete.{k}" for k, _ in numeric_fields(CompletionConfig())]

    def run(name: str | None, value) -> Outputs:
        cfg = GridConfig()
        kind, _, field = (name or "").partition(".")
        if kind == "grid":
            cfg = with_field(cfg, field, value)
        if kind == "complete":
            grid_pass.CompletionConfig = lambda **kw: CompletionConfig(**{field: value, **kw})
        try:
            return [_plain(det._grid_looks(p.grey, p.box, p.out, cfg)[0]) for p in pending]
        finally:
            grid_pass.CompletionConfig = CompletionConfig

    return names, run, len(pending)


def aprilgrid_runner(every: int) -> tuple[list[str], Callable[[str | None, object], Outputs], int]:
    """The AprilGrid's numbers, a function (name, value) -> outputs per frame, and the frames' count."""
    from calib_eval.detection.tags import TagEvalConfig, render_set

    board = make_target(TargetConfig(kind="aprilgrid"))
    ecfg = TagEvalConfig(per_fov=50, conditions=[], n_empty=0)  # the frames bench_tags times
    out = Path("report") / f"tags_{ecfg.seed}_{ecfg.per_fov}"
    render_set(ecfg, board, out)
    det = Detector(target=board)
    greys = [det._grey(cv2.imread(str(p), cv2.IMREAD_GRAYSCALE)) for p in sorted((out / "images").glob("*.png"))[::every]]

    def run(name: str | None, value) -> Outputs:
        cfg = TagConfig() if name is None else with_field(TagConfig(), name, value)
        return [_plain(tag_pass(g, board, cfg)) for g in greys]

    return [k for k, _ in numeric_fields(TagConfig())], run, len(greys)


def _plain(r) -> tuple[np.ndarray, np.ndarray]:
    return np.asarray(r.ids).copy(), np.round(np.asarray(r.xy, np.float64), 4)


def changed(base: Outputs, other: Outputs) -> int:
    """Frames whose ids or positions differ."""
    return sum(1 for (a, x), (b, y) in zip(base, other) if not (np.array_equal(a, b) and np.array_equal(x, y)))


def sweep(names: list[str], run: Callable, defaults: dict[str, int | float], out: Path) -> dict:
    """Each number of ``names`` halved and doubled (:func:`perturbed`); rows written to ``out`` as they are done (resumed from it)."""
    rows = json.loads(out.read_text()) if out.is_file() else {}
    base = run(None, None)
    n_base = sum(len(i) for i, _ in base)
    for i, name in enumerate(names):
        if name in rows:
            continue
        row: dict = {"value": defaults[name]}
        for v in perturbed(defaults[name]):
            try:
                res = run(name, v)
            except Exception as e:  # noqa: BLE001 (a value the pass refuses is a finding, not the sweep's end)
                row[repr(v)] = {"error": f"{type(e).__name__}: {e}"[:200]}
                continue
            row[repr(v)] = {"frames_changed": changed(base, res), "corners": sum(len(k) for k, _ in res) - n_base}
        rows[name] = row
        tmp = out.with_suffix(".tmp")
        tmp.write_text(json.dumps(rows, indent=1) + "\n")
        os.replace(tmp, out)
        print(f"[{i + 1}/{len(names)}] {name} = {defaults[name]}: {row}", file=sys.stderr, flush=True)
    return rows


def table(rows: dict, frames: int) -> str:
    """A markdown table of ``rows``: every number, the frames changed at half and at twice its value."""
    lines = [f"| number | value | frames changed at half / twice (of {frames}) | corners at half / twice |", "| --- | ---: | ---: | ---: |"]
    for name, row in rows.items():
        cells = [v for k, v in row.items() if k != "value"]
        if not cells:
            lines.append(f"| `{name}` | {row['value']} | (a switch: not swept) | |")
            continue
        ch = " / ".join(str(c.get("frames_changed", "error")) for c in cells)
        co = " / ".join(f"{c.get('corners', 0):+d}" for c in cells)
        lines.append(f"| `{name}` | {row['value']} | {ch} | {co} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.benchmark.number_sweep", description=__doc__.split("\n")[0])
    ap.add_argument("target", choices=["checkerboard", "aprilgrid"])
    ap.add_argument("--json", type=Path, required=True, help="rows go here (and a run resumes from it)")
    ap.add_argument("--sets", type=Path, default=Path("runs/regression/sets"), help="the regression's rendered sets (checkerboard)")
    ap.add_argument("--every", type=int, default=8, help="every N-th frame")
    ap.add_argument("--md", type=Path, help="also write the table here")
    args = ap.parse_args(argv)
    keep_image_buffers()
    if args.target == "checkerboard":
        names, run, frames = checkerboard_runner(args.sets, args.every)
        defaults = {f"grid.{k}": v for k, v in numeric_fields(GridConfig())}
        defaults.update({f"complete.{k}": v for k, v in numeric_fields(CompletionConfig())})
    else:
        names, run, frames = aprilgrid_runner(args.every)
        defaults = dict(numeric_fields(TagConfig()))
    rows = sweep(names, run, defaults, args.json)
    if args.md:
        args.md.write_text(table(rows, frames))
    dormant = [k for k, r in rows.items() if len(r) > 1 and all(c.get("frames_changed") == 0 for k2, c in r.items() if k2 != "value")]
    print(f"{len(dormant)} of {len(rows)} numbers change no frame at half or twice their value: {', '.join(dormant)}")


if __name__ == "__main__":
    main()
