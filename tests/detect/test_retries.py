"""The retry schedule (cotrain.detect.retries): which looks each target's config gives, in order,
what each overrides, and that the first look finding a corner is the one reported."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cotrain.detect.grid_config import GREY_PRINT_GAIN, GridConfig
from cotrain.detect.retries import (
    CONTRAST_RAISED,
    FIRST,
    SMALL_CELLS,
    aprilgrid_looks,
    checkerboard_looks,
    first_found,
)
from cotrain.detect.tag_config import TagConfig


def test_the_checkerboard_schedule_raises_the_contrast_only_for_grey_prints():
    """By default one look (with half resolution); ``--grey-print`` adds the raised frame, whose
    placement needs the geometry: the two margins it overrides, and nothing else."""
    (only,) = checkerboard_looks(GridConfig())
    assert only.name == FIRST and only.half_resolution and not only.gained and only.config(GridConfig()) == GridConfig()
    cfg = GridConfig(retry_gain=GREY_PRINT_GAIN)
    first, raised = checkerboard_looks(cfg)
    assert first.name == FIRST and raised.name == CONTRAST_RAISED and raised.gained and raised.half_resolution
    strict = raised.config(cfg)
    assert strict.min_margin == cfg.retry_min_margin and strict.min_geometry_margin == cfg.retry_min_geometry_margin
    changed = {k for k, v in vars(strict).items() if v != getattr(cfg, k)}
    assert changed <= {"min_margin", "min_geometry_margin"}


def test_the_aprilgrid_schedule_and_its_switches():
    """Three looks by default: the small cells, then the raised frame read as the first look (its
    own settings, half resolution too). Each switch takes out only its own look."""
    cfg = TagConfig()
    looks = aprilgrid_looks(cfg)
    assert [x.name for x in looks] == [FIRST, SMALL_CELLS, CONTRAST_RAISED]
    assert [x.half_resolution for x in looks] == [True, False, True]
    assert [x.gained for x in looks] == [False, False, True]
    small = looks[1].config(cfg)
    assert small.seed_axis_angle == cfg.seed_axis_angle and small.min_cell_px == cfg.retry_min_cell_px
    assert looks[2].config(cfg) == cfg
    assert [x.name for x in aprilgrid_looks(TagConfig(retry_gain=1.0))] == [FIRST, SMALL_CELLS]
    assert [x.name for x in aprilgrid_looks(TagConfig(retry_min_cell_px=1.0))] == [FIRST, CONTRAST_RAISED]


@dataclass
class _Found:
    ids: np.ndarray


def test_first_found_reads_no_look_after_the_one_that_finds():
    """The first look with a corner is reported with its look; later looks are never read; where
    none finds anything, the first look's (empty) result."""
    looks = aprilgrid_looks(TagConfig())
    read = []

    results = {}

    def reader(finds_at: str):
        def read_look(look):
            read.append(look.name)
            results[look.name] = _Found(np.arange(3) if look.name == finds_at else np.zeros(0, int))
            return results[look.name]

        return read_look

    result, look = first_found(looks, reader(SMALL_CELLS))
    assert look.name == SMALL_CELLS and len(result.ids) == 3 and read == [FIRST, SMALL_CELLS]
    read.clear()
    result, look = first_found(looks, reader("none"))
    assert look.name == FIRST and len(result.ids) == 0 and read == [x.name for x in looks]
    assert result is results[FIRST]  # the first look's own result, not a later look's


def test_a_detection_names_its_look():
    """A frame where nothing is found reports the first look; the slot read-out, which has no
    schedule, no look."""
    from cotrain.detect.detector import Detector

    flat = (0.5 + 0.02 * np.random.default_rng(0).standard_normal((360, 480))).astype(np.float32)
    grid = Detector(threads=1).detect(flat)
    assert len(grid.ids) == 0 and grid.look == FIRST
    assert Detector(threads=1, mode="slots").detect(flat).look == ""
