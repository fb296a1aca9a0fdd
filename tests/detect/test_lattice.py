"""Lattice growth helpers (cotrain.detect.lattice): step prediction and skipped-corner checks."""

import numpy as np
import pytest

from cotrain.detect.lattice import Lattice, next_step, skipped_corners
from cotrain.detect.saddle import saddle_response
from tests.detect.boards import NX, NY, board_image


def test_lattices_with_skipped_corners_are_recognised():
    """The true lattice has no X-junction at its step midpoints or cell centres; one grown with
    double steps along a, or with knight's moves (two along, one across: colours still
    alternate), has them at most of its steps or cells."""
    img, q = board_image(size=(360, 260))
    response = saddle_response(img)

    def lattice(ij: list[tuple[int, int]], ab: list[tuple[int, int]]) -> Lattice:
        ids = [j * NX + i for i, j in ij]
        return Lattice(q[ids], np.array(ab), np.zeros(len(ab), bool))

    true = [(i, j) for i in range(NX) for j in range(NY)]
    assert skipped_corners(lattice(true, true), response) == 0.0
    double = [(2 * a, b) for a in range(4) for b in range(NY)]
    assert skipped_corners(lattice(double, [(a, b) for a in range(4) for b in range(NY)]), response) > 0.8
    knight = [(2 * a + 1, b - a + 3) for a in range(4) for b in range(3)]
    knight_ab = [(a, b) for a in range(4) for b in range(3)]
    assert all(0 <= i < NX and 0 <= j < NY for i, j in knight)
    assert skipped_corners(lattice(knight, knight_ab), response) > 0.8


def test_next_step_continues_a_perspective_line_and_an_arc():
    # Equal steps on a line seen in perspective: x = f X / Z along X = t, Z = 2 + 0.5 t.
    t = np.arange(4.0)
    p = np.stack([500 * t / (2 + 0.5 * t), 100 + 0 * t], 1)
    np.testing.assert_allclose(next_step(p[1] - p[0], p[2] - p[1]), p[3] - p[2], atol=1e-9)
    # ... and receding the other way (growing steps).
    p = np.stack([300 * t / (4 - 0.6 * t), 0 * t], 1)
    np.testing.assert_allclose(next_step(p[1] - p[0], p[2] - p[1]), p[3] - p[2], atol=1e-9)
    # Equal chords of a circle: the step turns by the same angle again.
    a = 0.25 * t
    p = 80 * np.stack([np.cos(a), np.sin(a)], 1)
    np.testing.assert_allclose(next_step(p[1] - p[0], p[2] - p[1]), p[3] - p[2], atol=1e-9)
    # Equal steps stay equal; the ratio and the turn are clamped.
    np.testing.assert_allclose(next_step(np.array([10.0, 0]), np.array([10.0, 0])), [10, 0])
    np.testing.assert_allclose(np.linalg.norm(next_step(np.array([10.0, 0]), np.array([40.0, 0]))), 80)
    w = next_step(np.array([10.0, 0]), np.array([0.0, 10]))
    assert np.degrees(np.arctan2(w[1], w[0])) == pytest.approx(120)
