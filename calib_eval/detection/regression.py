"""Every set the repo keeps, through our detector, set by set: the table a change of the detector is
judged by ("no regression, set by set").

    python -m calib_eval.detection.regression [--out runs/regression] [--sets DIR] [--only NAME ...] [--list]
    python -m calib_eval.detection.regression --compare BEFORE.json AFTER.json

The sets (:data:`KEPT_SETS`) are the evaluation set with its rows of hard frames, the tuning sets,
the held-out sets, the AprilGrid sets, the independent renderer's sets for both targets and the
real frames of ``../shared/real``. Each is rendered once under ``OUT/sets/NAME`` by its own
renderer (reused while its settings are the same) and scored as its own command scores it:
``calib-eval detection`` (:func:`calib_eval.detection.evaluation.score`), ``python -m
calib_eval.detection.tags`` (:func:`calib_eval.detection.tags.score_frame`), ``python -m
calib_eval.detection.foreign``, ``python -m calib_eval.detection.real_frames``. Per set and per
row of hard frames: recall of detectable corners within 3 px with their own id, wrong corners
(reported more than 3 px from their id's label), and frames without a target that got a report.

``OUT/regression.json`` collects the rows; each set's row is also kept in ``OUT/rows/NAME.json``
under the detector's cache key, so a run stopped half-way goes on where it stopped and a set
whose detector and frames did not change is not detected again. ``--compare`` prints the table
of two such files and flags every row whose recall fell by more than 0.005 or whose wrong
corners grew; it exits 1 where one did.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from cotrain.io.detections import write_json_atomic
from cotrain.progress import progress_bar

RECALL_TOLERANCE = 0.005  # a row's recall may fall by this much before it counts as a regression (the figure)


@dataclass(frozen=True)
class KeptSet:
    """One set the repo keeps: its renderer (``source``) and that renderer's settings."""

    name: str  # row name and folder name
    source: str  # "rendered" (calib-eval detection), "tags" (the AprilGrid evaluation), "foreign" (independent renderer), "real"
    settings: tuple = ()  # (field, value) pairs of the renderer's config (EvalConfig, TagEvalConfig, ForeignConfig)
    tuning: bool = False  # thresholds were set on it (calib_eval.detection.sets): never reported as held out


def _kept(name: str, source: str, **settings) -> KeptSet:
    """A kept set; a rendered one, or one of the independent renderer's, is a tuning set where
    :mod:`calib_eval.detection.sets` lists it (``TUNING_SETS``, ``FOREIGN_TUNING``)."""
    from calib_eval.detection.evaluation import EvalConfig
    from calib_eval.detection.sets import FOREIGN_TUNING, is_tuning
    from calib_eval.detection.tags import TagEvalConfig

    tuning = name in FOREIGN_TUNING
    if source in ("rendered", "tags"):
        cfg = (EvalConfig if source == "rendered" else TagEvalConfig)(**settings)
        tuning = is_tuning("checkerboard" if source == "rendered" else "aprilgrid", cfg.seed, cfg.width, cfg.height)
    return KeptSet(name, source, tuple(sorted(settings.items())), tuning)


_HELD = dict(per_fov=25, n_empty=5, per_condition=24)  # the sets of docs/results/held_out_checkerboard.md
_HARD_1920 = ["large squares at the rim", "glare", "under-exposed", "over-exposed"]
_EXPOSED_1920 = ["large squares at the rim", "under-exposed", "over-exposed"]
# The rows of the held-out sets with the most wrong corners, drawn again with other seeds (tuning sets).
_HARD_ROWS = dict(fovs=[180], per_fov=1, n_empty=0, conditions=["glare", "strong vignetting", "motion blur"], per_condition=48)
_BLUR_ROWS = dict(fovs=[180], per_fov=1, n_empty=0, conditions=["motion blur"], per_condition=96)

KEPT_SETS = (
    _kept("evaluation_2026_1280x720", "rendered"),
    _kept("seed7_1280x720", "rendered", seed=7),
    _kept("seed11_1280x720", "rendered", seed=11),
    _kept("seed2026_640x480", "rendered", seed=2026, width=640, height=480),
    _kept("seed7_1920x1080", "rendered", seed=7, width=1920, height=1080, **_HELD),
    _kept("seed31_640x480", "rendered", seed=31, width=640, height=480, **_HELD),
    _kept("seed97_1280x720", "rendered", seed=97, **_HELD),
    _kept("seed99_1024x1024", "rendered", seed=99, width=1024, height=1024, **_HELD),
    _kept("seed11_1920x1080", "rendered", seed=11, width=1920, height=1080, per_fov=12, n_empty=4, conditions=_HARD_1920),
    _kept(
        "seed31_1920x1080",
        "rendered",
        seed=31,
        width=1920,
        height=1080,
        fovs=[180],
        per_fov=1,
        n_empty=0,
        conditions=_HARD_1920[:1] + _HARD_1920[2:],
    ),
    _kept("seed5150_1920x1080", "rendered", seed=5150, width=1920, height=1080, **_HELD),
    _kept("seed5151_640x480", "rendered", seed=5151, width=640, height=480, **_HELD),
    _kept("seed5152_1920x1080", "rendered", seed=5152, width=1920, height=1080, **_HARD_ROWS),
    _kept("seed5153_1024x1024", "rendered", seed=5153, width=1024, height=1024, **_BLUR_ROWS),
    _kept("tags_2027_1280x720", "tags"),
    _kept("tags_2042_640x480", "tags", seed=2042, width=640, height=480, per_fov=12, per_condition=0),
    _kept("tags_2045_640x480", "tags", seed=2045, width=640, height=480, per_fov=15, per_condition=0),
    _kept("tags_2043_1920x1200", "tags", seed=2043, width=1920, height=1200, per_fov=12, per_condition=0),
    _kept("foreign_checkerboard", "foreign"),
    _kept("foreign_checkerboard_photo", "foreign", photo=True),
    _kept("foreign_checkerboard_isp", "foreign", isp=True),
    _kept("foreign_checkerboard_defocus", "foreign", defocus=2.5),
    _kept("foreign_aprilgrid", "foreign", target="aprilgrid"),
    _kept("foreign_aprilgrid_photo", "foreign", target="aprilgrid", photo=True),
    _kept("foreign_aprilgrid_isp", "foreign", target="aprilgrid", isp=True),
    _kept("foreign_aprilgrid_defocus", "foreign", target="aprilgrid", defocus=2.5),
    _kept("real_boofcv", "real", folder="boofcv_fisheye_chessboard/images"),
    KeptSet("real_ros_stereo", "real", (("folder", "ros_fisheye_stereo/images"),), tuning=True),  # right-0000.png: the half-resolution gate
)


@dataclass
class Tally:
    """Counts of one row: detectable corners, those found with their own id, wrong corners."""

    detectable: int = 0
    hits: int = 0
    wrong: int = 0

    def add(self, detectable: int, hits: int, wrong: int) -> None:
        self.detectable, self.hits, self.wrong = self.detectable + detectable, self.hits + hits, self.wrong + wrong

    def row(self) -> dict:
        return {"recall": self.hits / max(1, self.detectable), "detectable": self.detectable, "hits": self.hits, "wrong": self.wrong}


def _predict(detector, paths: list[Path], desc: str) -> list[tuple[list[int], np.ndarray]]:
    """Our detector on each file: (ids, (K, 2) xy)."""
    from cotrain.detect.images import load_image

    out = []
    for p in progress_bar(paths, desc=desc, unit="img"):
        d = detector.detect(load_image(p))
        out.append((d.ids.tolist(), np.asarray(d.xy)))
    return out


def _rows(tallies: dict[str, Tally], empty_reports: int, n_empty: int) -> dict:
    """A set's rows: "FoV rows" (every frame of no hard condition) and one per hard condition."""
    return {"rows": {k: t.row() for k, t in tallies.items()}, "empty_with_reports": empty_reports, "empty_frames": n_empty}


def _score_labelled(detector, labels: list[dict], images: Path, board, desc: str) -> dict:
    """Score frames labelled as ``calib-eval detection``'s sets are (detectable flags per corner)."""
    from calib_eval.detection.evaluation import score_image

    found = _predict(detector, [images / lab["image"] for lab in labels], desc)
    tallies: dict[str, Tally] = {}
    empty = n_empty = 0
    for lab, (ids, xy) in zip(labels, found):
        if not lab.get("has_target", True):
            n_empty, empty = n_empty + 1, empty + int(len(ids) > 0)
            continue
        pred = [[i, float(x), float(y)] for i, (x, y) in zip(ids, xy)]
        gt, vis, det = (np.asarray(lab[k]) for k in ("corners", "visible", "detectable"))
        s = score_image(pred, True, gt, vis, det, symmetries=board.symmetries())
        tallies.setdefault(lab.get("condition") or "FoV rows", Tally()).add(s["n_detectable"], len(s["hits"]), s["n_outliers"])
    return _rows(tallies, empty, n_empty)


def _run_rendered(s: KeptSet, out: Path, detector_for) -> dict:
    from calib_eval.detection.evaluation import EvalConfig, load_or_render
    from cotrain.targets import make_target

    cfg = EvalConfig(**dict(s.settings))
    meta = load_or_render(cfg, out, progress=True)
    board = make_target(cfg.target)
    return _score_labelled(detector_for(board), meta["labels"], out / "images", board, s.name)


def _run_tags(s: KeptSet, out: Path, detector_for) -> dict:
    from calib_eval.detection.tags import TagEvalConfig, render_set, score_frame
    from cotrain.targets import TargetConfig, make_target

    cfg = TagEvalConfig(**dict(s.settings))
    board = make_target(TargetConfig(kind="aprilgrid"))
    labels = render_set(cfg, board, out)
    found = _predict(detector_for(board), [out / "images" / lab["image"] for lab in labels], s.name)
    tallies: dict[str, Tally] = {}
    empty = n_empty = 0
    for lab, (ids, xy) in zip(labels, found):
        if not lab["fov"] and not lab["condition"]:
            n_empty, empty = n_empty + 1, empty + int(len(ids) > 0)
            continue
        r = score_frame(ids, list(xy), lab, cfg.min_tag_px)
        tallies.setdefault(lab["condition"] or "FoV rows", Tally()).add(int(r["det"].sum()), int(r["hit"].sum()), r["wrong"])
    return _rows(tallies, empty, n_empty)


def _run_foreign(s: KeptSet, out: Path, detector_for) -> dict:
    from calib_eval.detection.foreign import ForeignConfig, make_board, render_set

    cfg = ForeignConfig(**dict(s.settings))
    board = make_board(cfg)
    same = {"config": json.loads(json.dumps(asdict(cfg))), "target": board.to_json()}
    old = out / "labels.json"
    if old.is_file() and {k: json.loads(old.read_text()).get(k) for k in same} == same:
        labels = json.loads(old.read_text())["labels"]
    else:
        labels = render_set(out, cfg)
    return _score_labelled(detector_for(board), labels, out / "images", board, s.name)


def _real_board(spec):
    from cotrain.targets import Checkerboard, TargetConfig

    return Checkerboard(TargetConfig(squares_x=spec.squares_x, squares_y=spec.squares_y))


def _run_real(s: KeptSet, out: Path, detector_for) -> dict:
    from calib_eval.detection.real_frames import REAL, SETS, evaluate_set

    spec = next(r for r in SETS if r.folder == dict(s.settings)["folder"])
    if not (REAL / spec.folder).is_dir():
        return {"missing": f"no {REAL / spec.folder}"}
    r = evaluate_set(spec, detector=detector_for(_real_board(spec)))
    return {
        "rows": {
            "whole boards": {"recall": r["whole"]["ours"] / max(1, r["frames"]), "hits": r["whole"]["ours"], "detectable": r["frames"]}
        },
        "opencv_whole_ours_not": r["opencv_whole_ours_not"],
        "whole": r["whole"],
    }


RUNNERS = {"rendered": _run_rendered, "tags": _run_tags, "foreign": _run_foreign, "real": _run_real}


def target_detector(board, grid, tags):
    """The detector of ``board`` (one thread), under its own pass's settings: ``tags`` (a
    :class:`TagConfig`) for an AprilGrid, ``grid`` (a :class:`GridConfig`) for a checkerboard (an
    AprilGrid's Detector refuses grid settings)."""
    from cotrain.detect.detector import Detector
    from cotrain.targets import AprilGrid

    own = {"tags": tags} if isinstance(board, AprilGrid) else {"grid": grid}
    return Detector(target=board, threads=1, **own)


def run(out: Path, only: list[str] | None = None, sets: Path | None = None, grid=None, tags=None) -> dict:
    """Every kept set (or those named in ``only``) through the detector of its target, under
    ``grid`` (a checkerboard's :class:`GridConfig`) and ``tags`` (an AprilGrid's
    :class:`TagConfig`), default their defaults: {set name: row}. The frames are rendered under
    ``sets`` (default ``out/sets``); rows already in ``out/rows`` under the same detector key are
    reused."""
    from cotrain.detect.detector import Detector
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.tag_config import TagConfig

    sets, grid, tags = sets or out / "sets", grid or GridConfig(), tags or TagConfig()
    detectors: dict[str, Detector] = {}

    def detector_for(board) -> Detector:
        key = json.dumps(board.to_json(), sort_keys=True)
        if key not in detectors:
            detectors[key] = target_detector(board, grid, tags)
        return detectors[key]

    results = {}
    for s in KEPT_SETS:
        if only and s.name not in only:
            continue
        done = out / "rows" / f"{s.name}.json"
        key = json.loads(json.dumps({"set": asdict(s), "detector": _detector_key(s, grid, tags)}))  # as it reads back
        if done.is_file() and json.loads(done.read_text()).get("key") == key:
            results[s.name] = json.loads(done.read_text())["row"]
            continue
        row = RUNNERS[s.source](s, sets / s.name, detector_for) | {"tuning": s.tuning}
        if "missing" not in row:  # a set that could not be read is looked for again next time
            write_json_atomic({"key": key, "row": row}, done)
        results[s.name] = row
        rows = ", ".join(f"{k} {v['recall']:.4f}/{v.get('wrong', 0)}" for k, v in row.get("rows", {}).items())
        print(f"{s.name}: {rows}", file=sys.stderr)
    write_json_atomic(results, out / "regression.json")
    return results


def _detector_key(s: KeptSet, grid, tags) -> dict:
    """What decides our output on the set: the detector's settings for its target kind."""
    from calib_eval.detection.evaluation import BENCH_VERSION
    from cotrain.detect.detector import OUTPUT_VERSION, settings
    from cotrain.detect.onnx_model import default_grid_model_path
    from cotrain.render.renderer import LABEL_VERSION

    frames = {"bench_version": BENCH_VERSION, "label_version": LABEL_VERSION}  # re-rendered sets are scored again
    aprilgrid = dict(s.settings).get("target") == "aprilgrid" or s.source == "tags"
    if aprilgrid:
        return {"version": OUTPUT_VERSION, "tag_pass": settings(tags)} | frames
    model = default_grid_model_path()
    return {"version": OUTPUT_VERSION, "grid": settings(grid), "model": [model.name, model.stat().st_size]} | frames


def compare(before: dict, after: dict) -> tuple[str, int]:
    """A markdown table of two runs, row by row, and the number of rows that regressed (recall
    down by more than :data:`RECALL_TOLERANCE`, or more wrong corners, or more empty frames with
    reports)."""
    if not isinstance(before, dict) or not isinstance(after, dict):
        raise ValueError("not a regression.json (a set name -> row mapping)")
    lines = ["| set | row | recall before -> after | wrong before -> after | |", "| --- | --- | --- | --- | --- |"]
    bad = 0
    for name in before:
        b, a = before[name], after.get(name, {})
        for row in b.get("rows", {}):
            rb, ra = b["rows"][row], a.get("rows", {}).get(row)
            if ra is None:  # a set or a row that is no longer scored hides what it measured
                bad += 1
                lines.append(f"| {name} | {row} | {rb['recall']:.4f} -> missing | | **regressed** |")
                continue
            worse = ra["recall"] < rb["recall"] - RECALL_TOLERANCE or ra.get("wrong", 0) > rb.get("wrong", 0)
            bad += worse
            tag = " (tuning)" if a.get("tuning") else ""
            lines.append(
                f"| {name}{tag} | {row} | {rb['recall']:.4f} -> {ra['recall']:.4f} | {rb.get('wrong', 0)} -> {ra.get('wrong', 0)} "
                f"| {'**regressed**' if worse else ''} |"
            )
        if a.get("empty_with_reports", 0) > b.get("empty_with_reports", 0):
            bad += 1
            counts = f"{b.get('empty_with_reports', 0)} -> {a['empty_with_reports']}"
            lines.append(f"| {name} | frames without a target, with reports | | {counts} | **regressed** |")
    return "\n".join(lines), bad


def table(results: dict) -> str:
    """One run's rows as markdown."""
    lines = ["| set | row | recall | hits / detectable | wrong |", "| --- | --- | --- | --- | --- |"]
    for name, r in results.items():
        tag = " (tuning)" if r.get("tuning") else ""
        for row, v in r.get("rows", {}).items():
            recall = f"{v['recall']:.4f}" if v["detectable"] else "no corner to find"  # e.g. FoV rows of a set of hard rows only
            lines.append(f"| {name}{tag} | {row} | {recall} | {v['hits']} / {v['detectable']} | {v.get('wrong', '')} |")
        if r.get("empty_frames"):
            lines.append(f"| {name}{tag} | frames without a target, with reports | | {r['empty_with_reports']} / {r['empty_frames']} | |")
    return "\n".join(lines)


def _overridden(name: str, pairs: list[str]):
    """The config class ``name`` (GridConfig or TagConfig) with ``FIELD=VALUE`` pairs set (values
    read as YAML: numbers, true / false, .inf); ValueError (one line) for an unknown field. For
    TagConfig, ``grid.FIELD=VALUE`` sets a field of the grid settings the tag pass shares
    (``TagConfig.grid``: its lens FoV, ``agree_radius``, ...) and ``complete.FIELD=VALUE`` one of
    its completion settings (``TagConfig.complete``: also its candidates' symmetry, ray circle and
    smallest gap)."""
    import dataclasses

    import yaml

    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.print_model import CompletionConfig
    from cotrain.detect.tag_config import TagConfig

    cls = {"GridConfig": GridConfig, "TagConfig": TagConfig}[name]
    nested = {"grid": GridConfig, "complete": CompletionConfig} if cls is TagConfig else {}
    names = {f.name for f in dataclasses.fields(cls)} - set(nested)
    names |= {f"{part}.{f.name}" for part, sub in nested.items() for f in dataclasses.fields(sub)}
    values: dict = {}
    parts: dict[str, dict] = {part: {} for part in nested}
    for pair in pairs:
        key, sep, value = pair.partition("=")
        if not sep or key not in names:
            raise ValueError(f"{pair!r}: not FIELD=VALUE with a field of {name}")
        part, _, field_name = key.rpartition(".")
        got, default = yaml.safe_load(value), getattr(nested[part]() if part else cls(), field_name)
        numeric = isinstance(default, (int, float)) and not isinstance(default, bool)
        if isinstance(default, bool) and not isinstance(got, bool):
            raise ValueError(f"{pair!r}: {key} is true or false")
        if numeric and (isinstance(got, bool) or not isinstance(got, (int, float))):
            raise ValueError(f"{pair!r}: {key} is a number")
        (parts[part] if part else values)[field_name] = got
    values.update({part: nested[part](**got) for part, got in parts.items() if got})
    return cls(**values)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m calib_eval.detection.regression", description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=Path("runs/regression"), help="rows and regression.json go here")
    ap.add_argument("--sets", type=Path, help="the rendered sets (default OUT/sets): two runs can share them")
    ap.add_argument("--only", nargs="+", metavar="NAME", help="these kept sets only (--list names them)")
    ap.add_argument("--list", action="store_true", help="name the kept sets and stop")
    ap.add_argument("--grid", nargs="+", default=[], metavar="FIELD=VALUE", help="the checkerboard's GridConfig fields (a rule's ablation)")
    ap.add_argument("--tags", nargs="+", default=[], metavar="FIELD=VALUE", help="the AprilGrid's TagConfig fields")
    ap.add_argument("--compare", nargs=2, type=Path, metavar=("BEFORE", "AFTER"), help="two regression.json files")
    args = ap.parse_args(argv)
    if args.list:
        for s in KEPT_SETS:
            print(f"{s.name}\t{s.source}\t{'tuning' if s.tuning else 'reported'}\t{dict(s.settings)}")
        return 0
    if args.compare:
        missing = [p for p in args.compare if not p.is_file()]
        if missing:
            print(f"regression: no file {missing[0]}", file=sys.stderr)
            return 2
        try:
            text, bad = compare(*(json.loads(p.read_text()) for p in args.compare))
        except (ValueError, KeyError, TypeError) as e:
            print(f"regression: {args.compare[0]} / {args.compare[1]}: {e}", file=sys.stderr)
            return 2
        print(text + f"\n\n{bad} row(s) regressed")
        return 1 if bad else 0
    unknown = sorted(set(args.only or []) - {s.name for s in KEPT_SETS})
    if unknown:
        print(f"regression: no kept set {unknown[0]} (--list names them)", file=sys.stderr)
        return 2
    try:
        grid, tags = _overridden("GridConfig", args.grid), _overridden("TagConfig", args.tags)
    except ValueError as e:
        print(f"regression: {e}", file=sys.stderr)
        return 2
    print(table(run(args.out, args.only, args.sets, grid, tags)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
