"""Each target's print and corner coordinates in numpy (what the detector reads, without torch)
are the torch ones the renderer draws."""

import numpy as np
import pytest
import torch

from cotrain.targets import AprilGrid, Checkerboard, TargetConfig


@pytest.mark.parametrize("board", [Checkerboard(), Checkerboard(TargetConfig(squares_x=7, squares_y=5, square_size=0.03)), AprilGrid()])
def test_numpy_print_and_corners_are_the_torch_ones(board):
    """The detector reads the print and the corners' board coordinates in numpy (no torch): the
    same values as the renderer's torch, at random points, on every corner and on grid lines."""
    x0, y0, x1, y1 = board.extent()
    rng = np.random.default_rng(3)
    P = np.concatenate(
        [
            rng.uniform([x0 - 0.02, y0 - 0.02], [x1 + 0.02, y1 + 0.02], (5000, 2)),
            board.board_xy(),  # exactly on corners (grid lines cross there)
            board.board_xy() + [[0.0, board.spacing / 3]],
        ]
    )
    v_np, c_np = board.intensity(P)
    v_t, c_t = board.intensity(torch.from_numpy(P))
    assert isinstance(v_np, np.ndarray) and v_np.dtype == np.float64
    np.testing.assert_array_equal(v_np, v_t.numpy())
    np.testing.assert_array_equal(c_np, c_t.numpy())
    assert board.board_xy().dtype == np.float64
    np.testing.assert_array_equal(board.points()[:, :2].numpy(), board.board_xy())
    np.testing.assert_array_equal(board.points()[:, 2].numpy(), 0.0)
