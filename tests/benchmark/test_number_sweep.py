"""The tuned-number sweep's pieces (calib_eval.benchmark.number_sweep): which values it tries,
how it sets a nested field, and what counts as a changed frame."""

import math

import numpy as np

from calib_eval.benchmark.number_sweep import changed, numeric_fields, perturbed, table, with_field
from cotrain.detect.grid_config import GridConfig
from cotrain.detect.tag_config import TagConfig


def test_every_number_and_only_numbers_is_swept():
    names = dict(numeric_fields(TagConfig()))
    assert names["max_hamming"] == TagConfig().max_hamming and names["complete.neighbours"] == TagConfig().complete.neighbours
    assert names["grid.min_rim_px"] == GridConfig().min_rim_px
    assert "complete.rounds" not in names  # None by default (until a round adds nothing): not a number
    assert "complete.lens" not in names and "grid.join_lattices" not in names  # switches are not numbers
    assert all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in names.values())


def test_halved_and_doubled_switches_left_alone():
    assert perturbed(0.3) == [0.15, 0.6]
    assert perturbed(7) == [4, 14] and perturbed(1) == [0, 2]  # an int halved rounds, but never back to itself
    assert perturbed(0.0) == [] and perturbed(math.inf) == [] and perturbed(-math.inf) == []


def test_a_nested_field_is_set_without_touching_the_rest():
    cfg = with_field(TagConfig(), "complete.min_corr", 0.9)
    assert cfg.complete.min_corr == 0.9 and cfg.complete.rounds == TagConfig().complete.rounds
    assert cfg.grid == TagConfig().grid and TagConfig().complete.min_corr != 0.9


def test_a_frame_changes_with_its_ids_or_positions():
    base = [(np.array([1, 2]), np.array([[0.0, 0.0], [1.0, 1.0]])), (np.array([], int), np.zeros((0, 2)))]
    assert changed(base, base) == 0
    moved = [(np.array([1, 2]), np.array([[0.0, 0.0], [1.0, 1.0001]])), base[1]]
    other = [base[0], (np.array([5]), np.array([[3.0, 3.0]]))]
    assert changed(base, moved) == 1 and changed(base, other) == 1
    md = table(
        {"a": {"value": 2, "1": {"frames_changed": 0, "corners": 0}, "4": {"frames_changed": 3, "corners": -5}}, "b": {"value": 0.0}}, 9
    )
    assert "| `a` | 2 | 0 / 3 | +0 / -5 |" in md and "(a switch: not swept)" in md and "(of 9)" in md
