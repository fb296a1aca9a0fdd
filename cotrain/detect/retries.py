"""The retry schedule: the looks a frame gets, in order, and what each one changes.

Every target reads a frame by a fixed, short list of :class:`Look` s. The first look reads the frame
as given, under the detector's own settings. Only where a look finds no corner at all does the next
one read the frame; the first look that finds any corner is reported, and
:attr:`cotrain.detect.detector.Detection.look` names it. So a reported corner was found under the
settings of exactly one look: the target's config with that look's :attr:`Look.overrides`.

A look may also read the frame at half resolution (:attr:`Look.half_resolution`): where the
full-resolution reading finds few corners (the tag pass: under half the board's; the
checkerboard: none), the half-resolution reading's corners are merged in where the print check
keeps them (:mod:`cotrain.detect.half_resolution`). That is not a retry: its corners join the
look's own, under the same settings.

What is not here, and why: enlarging a small frame (``TagConfig.min_side_px``) and scaling the
contrast thresholds with the board's contrast (:func:`cotrain.detect.grid_pass.contrast_scaled`)
happen in every look, the same way, before anything is found; they normalise the frame, they are not
second chances. Completion's rounds (:mod:`cotrain.detect.completion`) are one stage's own steps.

The schedules, as docs/detector.md tabulates them:

- checkerboard (:func:`checkerboard_looks`): ``first`` (with half resolution); ``contrast
  raised`` where ``GridConfig.retry_gain`` > 1 (``cotrain detect --grey-print``): the frame's
  contrast raised about its local mean, the network run again on it, the placement surer
  (``retry_min_margin``, ``retry_min_geometry_margin``), with half resolution.
- AprilGrid (:func:`aprilgrid_looks`): ``first`` (with half resolution); ``small cells`` where
  ``TagConfig.retry_min_cell_px`` < ``min_cell_px`` (tags of smaller data cells seed and are
  read); ``contrast raised`` where ``retry_gain`` > 1 (with half resolution). The small cells
  read the frame as the first look read it (its crop, lens and candidates), at full resolution
  only: the small tags they are for have had their half-resolution reading in the first look. The
  raised contrast is read at half resolution too: there most of its boards are found.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import TypeVar

from cotrain.detect.grid_config import GridConfig
from cotrain.detect.tag_config import TagConfig

FIRST = "first"
SMALL_CELLS = "small cells"
CONTRAST_RAISED = "contrast raised"


@dataclass(frozen=True)
class Look:
    """One reading of a frame in a target's retry schedule."""

    name: str  # what Detection.look and the docs call it
    gained: bool = False  # reads the frame with its contrast raised (images.local_gain) instead of the frame as given
    overrides: tuple[tuple[str, float], ...] = ()  # the target config's fields this look sets, (name, value), on top of the detector's
    half_resolution: bool = False  # where it finds few corners, the frame at half resolution too, merged (half_resolution)

    def config(self, cfg):
        """``cfg`` (a target's config dataclass) as this look reads the frame under it."""
        return replace(cfg, **dict(self.overrides)) if self.overrides else cfg


def checkerboard_looks(cfg: GridConfig) -> tuple[Look, ...]:
    """The grid pass's schedule under ``cfg`` (see the module's docstring)."""
    looks = [Look(FIRST, half_resolution=True)]
    if cfg.retry_gain > 1:
        # Placed surely by the geometry only: on the evaluation set (a tuning set), a board cut by two
        # occluders was placed half a turn wrong on the raised frame with the geometry 15 nats ahead
        # (the 19 right ones over the eight rendered sets: 15-90; at 20, 14 of them stay).
        strict = (("min_margin", cfg.retry_min_margin), ("min_geometry_margin", cfg.retry_min_geometry_margin))
        looks.append(Look(CONTRAST_RAISED, gained=True, overrides=strict, half_resolution=True))
    return tuple(looks)


def aprilgrid_looks(cfg: TagConfig) -> tuple[Look, ...]:
    """The tag pass's schedule under ``cfg`` (see the module's docstring).

    Why each look is a retry and not the first look's setting (the tuning log in CHANGELOG.md, tag
    pass step 12): widened in every frame, the cone changes which seeds grow first elsewhere and
    lost whole frames; seeds of data cells under a pixel, tried where larger tags show, can seed
    first and cover a large tag's corners with its data junctions; the contrast raised in every
    frame lost corners on the clean independent renderer's frames (0.994 -> 0.991), and a gain of
    2 placed one board wrongly."""
    looks = [Look(FIRST, half_resolution=True)]
    if cfg.retry_min_cell_px < cfg.min_cell_px:
        looks.append(Look(SMALL_CELLS, overrides=(("min_cell_px", cfg.retry_min_cell_px),)))
    if cfg.retry_gain > 1:
        looks.append(Look(CONTRAST_RAISED, gained=True, half_resolution=True))
    return tuple(looks)


R = TypeVar("R")


def first_found(looks: tuple[Look, ...], read: Callable[[Look], R]) -> tuple[R, Look]:
    """The result of the first of ``looks`` whose ``read(look)`` finds a corner (its ``ids`` not
    empty), and that look; where none does, the first look's result and the first look. Looks
    after the one that finds are not read."""
    first = None
    for look in looks:
        result = read(look)
        if len(result.ids):
            return result, look
        first = first or (result, look)
    return first
