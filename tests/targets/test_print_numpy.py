"""Each target's print and corner coordinates in numpy (what the detector reads, without torch)
are the torch ones the renderer draws."""

import numpy as np
import pytest
import torch

from cotrain.targets import AprilGrid, Checkerboard, TargetConfig


@pytest.mark.parametrize(
    "board",
    [
        Checkerboard(),
        Checkerboard(TargetConfig(squares_x=7, squares_y=5, square_size=0.03)),
        AprilGrid(),
        AprilGrid(TargetConfig(kind="aprilgrid", tag_cols=10, tag_rows=8, tag_size=0.03, tag_spacing=0.3)),
    ],
)
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
            # On the lines between cells (an AprilGrid's data cells are a tenth of its tag).
            (board.board_xy()[:, None] + np.arange(-3, 14)[None, :, None] * (board.spacing / 10)).reshape(-1, 2),
        ]
    )
    v_np, c_np = board.intensity(P)
    v_t, c_t = board.intensity(torch.from_numpy(P))
    assert isinstance(v_np, np.ndarray) and v_np.dtype == np.float64
    np.testing.assert_array_equal(v_np, v_t.numpy())
    np.testing.assert_array_equal(c_np, c_t.numpy())
    # One point alone (its coordinates numpy scalars) is read the same way, without torch types.
    v1, c1 = board.intensity(P[7])
    assert float(v1) == v_np[7] and float(c1) == c_np[7]
    # float32 points take numpy's general path (the compiled one reads float64).
    v32, _ = board.intensity(P[:50].astype(np.float32))
    np.testing.assert_array_equal(v32, board.intensity(torch.from_numpy(P[:50].astype(np.float32)))[0].numpy())
    assert board.board_xy().dtype == np.float64
    np.testing.assert_array_equal(board.points()[:, 2].numpy(), 0.0)


def test_board_coordinates_known_values():
    """Corner ids and board coordinates, worked out by hand: the checkerboard's corner (i, j) (id
    j nx + i) at ((i + 1) s, (j + 1) s); Kalibr's AprilGrid point (r, c) (id 2 tagCols r + c) at
    x = floor(c / 2) (1 + tagSpacing) tagSize + (c mod 2) tagSize, y likewise, in exact float64."""
    b = Checkerboard(TargetConfig(squares_x=7, squares_y=5, square_size=0.03))
    xy = b.board_xy()
    assert xy.shape == (24, 2)
    for i, j in ((0, 0), (5, 0), (0, 3), (2, 1), (5, 3)):
        assert xy[j * 6 + i].tolist() == [(i + 1) * 0.03, (j + 1) * 0.03]
    g = AprilGrid(TargetConfig(kind="aprilgrid", tag_cols=2, tag_rows=3, tag_size=0.055, tag_spacing=0.3))
    xy = g.board_xy()
    assert xy.shape == (24, 2)
    for r, c in ((0, 0), (0, 1), (0, 2), (0, 3), (5, 3), (3, 2), (4, 1)):
        x = (c // 2) * (0.055 + 0.3 * 0.055) + (c % 2) * 0.055
        y = (r // 2) * (0.055 + 0.3 * 0.055) + (r % 2) * 0.055
        assert xy[r * 4 + c].tolist() == pytest.approx([x, y], abs=1e-15)
    np.testing.assert_array_equal(g.points()[:, :2].numpy(), xy)
