"""The three ways a target is described, read into a :class:`~cotrain.targets.target.Target`:

- our config section (``target:`` in a training config; :class:`TargetConfig`, :func:`make_target`);
- the detection JSON's ``"target"`` entry (:func:`target_from_json`; written by ``Target.to_json``);
- a Kalibr target yaml (``target_type: checkerboard``, ``targetCols`` / ``targetRows`` counting
  inner corners, ``rowSpacingMeters`` / ``colSpacingMeters``; or ``target_type: aprilgrid``,
  ``tagCols``, ``tagRows``, ``tagSize``, ``tagSpacing``; :func:`target_from_kalibr`);
- a BoofCV target yaml (a serialised ``ConfigCalibrationTarget`` of ``type: CHESSBOARD``, its
  default: ``grid`` with ``numRows`` / ``numCols`` counting squares and ``shapeSize`` the square's
  side; :func:`target_from_boofcv`).

:func:`load_target` reads a file of our config section, Kalibr's or BoofCV's kind.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path

from cotrain.config import ConfigError, build, load_yaml
from cotrain.targets.aprilgrid import AprilGrid
from cotrain.targets.checkerboard import Checkerboard
from cotrain.targets.target import KINDS, Target, TargetConfig, TargetError


def make_target(cfg: TargetConfig | None = None) -> Target:
    """The Target a config section describes."""
    cfg = cfg or TargetConfig()
    if cfg.kind == "checkerboard":
        return Checkerboard(cfg)
    if cfg.kind == "aprilgrid":
        return AprilGrid(cfg)
    raise TargetError(f"target.kind: unsupported target {cfg.kind!r} (known: {', '.join(KINDS)})")


def _number(data: dict, key: str, where: str, kind: type = float, positive: bool = True):
    if key not in data:
        raise TargetError(f"{where}: missing {key!r}")
    v = data[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or (kind is int and not float(v).is_integer()):
        raise TargetError(f"{where}: {key} must be {'an integer' if kind is int else 'a number'}, not {v!r}")
    if positive and v <= 0:
        raise TargetError(f"{where}: {key} must be positive, not {v!r}")
    return kind(v)


def target_from_json(data: dict, where: str = "target") -> Target:
    """The Target of a detection JSON's ``"target"`` entry (docs/conventions.md)."""
    if not isinstance(data, dict):
        raise TargetError(f"{where}: expected a mapping, got {type(data).__name__}")
    kind = data.get("kind", "checkerboard")
    if kind not in KINDS:
        raise TargetError(f"{where}: unsupported target kind {kind!r} (known: {', '.join(KINDS)})")
    if kind == "aprilgrid":
        return make_target(
            TargetConfig(
                kind=kind,
                tag_cols=_number(data, "tag_cols", where, int),
                tag_rows=_number(data, "tag_rows", where, int),
                tag_size=_number(data, "tag_size", where),
                tag_spacing=_number(data, "tag_spacing", where),
            )
        )
    cfg = TargetConfig(
        kind=kind,
        squares_x=_number(data, "squares_x", where, int),
        squares_y=_number(data, "squares_y", where, int),
        square_size=_number(data, "square_size", where) if "square_size" in data else TargetConfig.square_size,
    )
    return make_target(cfg)


def target_from_kalibr(data: dict, where: str = "target yaml") -> Target:
    """The Target of a Kalibr target yaml (``target_type: checkerboard``: inner corners counted)."""
    kind = data.get("target_type")
    if kind == "checkerboard":
        cols = _number(data, "targetCols", where, int)
        rows = _number(data, "targetRows", where, int)
        dr = _number(data, "rowSpacingMeters", where)
        dc = _number(data, "colSpacingMeters", where)
        if not math.isclose(dr, dc, rel_tol=1e-6):
            raise TargetError(f"{where}: rowSpacingMeters {dr} and colSpacingMeters {dc} differ (only square checkers are supported)")
        return make_target(TargetConfig(squares_x=cols + 1, squares_y=rows + 1, square_size=dc))
    if kind == "aprilgrid":
        cfg = TargetConfig(
            kind="aprilgrid",
            tag_cols=_number(data, "tagCols", where, int),
            tag_rows=_number(data, "tagRows", where, int),
            tag_size=_number(data, "tagSize", where),
            tag_spacing=_number(data, "tagSpacing", where),
        )
        if "codeOffset" in data and data["codeOffset"] not in (0, None):
            raise TargetError(f"{where}: codeOffset {data['codeOffset']} is not supported (tags start at id 0)")
        return make_target(cfg)
    raise TargetError(f"{where}: unsupported Kalibr target_type {kind!r} (supported: checkerboard, aprilgrid)")


BOOFCV_KEY = "boofcv.alg.fiducial.calib.ConfigCalibrationTarget"  # the section a BoofCV target yaml keeps its target in


def target_from_boofcv(data: dict, where: str = "target yaml") -> Target:
    """The Target of a BoofCV target yaml (``ConfigCalibrationTarget``): a chessboard of
    ``grid.numCols`` x ``grid.numRows`` squares (columns along x) of side ``grid.shapeSize``, taken
    as metres."""
    section = data.get(BOOFCV_KEY)
    if not isinstance(section, dict):
        raise TargetError(f"{where}: {BOOFCV_KEY} must be a mapping")
    kind = str(section.get("type", "CHESSBOARD")).upper()
    if kind != "CHESSBOARD":
        raise TargetError(f"{where}: unsupported BoofCV target type {kind} (supported: CHESSBOARD)")
    grid = section.get("grid")
    if not isinstance(grid, dict):
        raise TargetError(f"{where}: the BoofCV target has no 'grid' mapping")
    cfg = TargetConfig(
        squares_x=_number(grid, "numCols", where, int),
        squares_y=_number(grid, "numRows", where, int),
        square_size=_number(grid, "shapeSize", where),
    )
    return make_target(cfg)


def target_from_flags(
    path: str | None, squares_x: int | None, squares_y: int | None, square_size: float | None, base: Target | None = None
) -> Target | None:
    """The board named on a command line: ``--target FILE``, or ``--squares-x X --squares-y Y``
    [``--square-size S``], or ``--square-size S`` alone (``base``, a checkerboard, with that square
    size). None when no flag names a board."""
    if path and (squares_x is not None or squares_y is not None or square_size is not None):
        raise TargetError("give the board either as --target or as --squares-x/--squares-y/--square-size")
    if path:
        return load_target(path)
    if (squares_x is None) != (squares_y is None):
        raise TargetError("give both --squares-x and --squares-y")
    if square_size is not None and square_size <= 0:
        raise TargetError("--square-size must be positive")
    if squares_x is not None:
        size = square_size if square_size is not None else (base.spacing if base is not None else TargetConfig.square_size)
        return make_target(TargetConfig(squares_x=squares_x, squares_y=squares_y, square_size=size, margin=0.0))
    if square_size is not None:
        if not isinstance(base, Checkerboard):
            raise TargetError("--square-size alone changes a checkerboard's square size; name the board too")
        return make_target(dataclasses.replace(base.cfg, square_size=square_size))
    return None


NOT_A_TARGET = (
    "not a calibration target: give a Kalibr target yaml (target_type: checkerboard or aprilgrid, as for kalibr_calibrate_cameras "
    "--target), a BoofCV target, or our target config (kind: checkerboard, squares_x, ...)"
)


def load_target(path: str | Path) -> Target:
    """A target file: a Kalibr target yaml (``target_type: ...``), a BoofCV one
    (``boofcv.alg.fiducial.calib.ConfigCalibrationTarget: ...``), or our ``target:`` config section
    (a file with a ``target:`` mapping, or the section's keys at the top level)."""
    try:
        data = load_yaml(path)
    except ConfigError as e:
        raise TargetError(str(e)) from None
    if not data:
        raise TargetError(f"{path}: describes no target (empty file)")
    if "target_type" in data:
        return target_from_kalibr(data, str(path))
    if BOOFCV_KEY in data:
        return target_from_boofcv(data, str(path))
    if not isinstance(data, dict):
        raise TargetError(f"{path}: {NOT_A_TARGET}")
    section = data.get("target", data)
    if not isinstance(section, dict):
        raise TargetError(f"{path}: 'target' must be a mapping")
    if "target" not in data and not set(section) & {f.name for f in dataclasses.fields(TargetConfig)}:
        what = " (it looks like a camchain: camera parameters, not the board)" if any(str(k).startswith("cam") for k in section) else ""
        raise TargetError(f"{path}: {NOT_A_TARGET}{what}")
    try:
        return make_target(build(TargetConfig, section, "target"))
    except ConfigError as e:
        raise TargetError(f"{path}: {e}") from None
