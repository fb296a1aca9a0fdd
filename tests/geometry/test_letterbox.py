"""The letterbox (input -> processing pixels) and the cell grid (processing pixels -> 1/4 cells)."""

import numpy as np
import torch

from cotrain.geometry.letterbox import CELLS, CellGrid, Letterbox


def test_letterbox_known_values_and_round_trip():
    box = Letterbox(1280, 720, (216, 384))
    assert box.scale == 0.3
    # Pixel centres: the top-left input pixel's centre maps to (0.5 s - 0.5); corners of the image stay corners.
    np.testing.assert_allclose(box.to_processing(np.array([[-0.5, -0.5], [1279.5, 719.5]])), [[-0.5, -0.5], [383.5, 215.5]])
    x = np.random.default_rng(0).uniform(0, 1280, (50, 2))
    np.testing.assert_allclose(box.to_input(box.to_processing(x)), x, atol=1e-9)
    t = torch.tensor(x)
    assert torch.allclose(box.to_input(box.to_processing(t)), t)


def test_letterbox_places_top_left():
    img = np.ones((480, 640), np.float32)
    canvas = Letterbox(640, 480, (216, 384)).apply(img)  # s = 0.45: 288 x 216
    assert canvas.shape == (216, 384)
    assert canvas[:, :288].min() > 0.999 and canvas[:, 288:].max() == 0.0


def test_cell_grid_centres():
    assert CELLS.stride == 4 and CELLS.offset == 1.5
    # Cell 0 covers processing pixels 0..3, centre 1.5; cell 2 covers 8..11.
    np.testing.assert_allclose(CELLS.to_pixel(np.array([0.0, 2.0])), [1.5, 9.5])
    np.testing.assert_allclose(CELLS.to_cell(CELLS.to_pixel(np.array([3.25]))), [3.25])
    assert CellGrid(2).offset == 0.5


def test_cell_sampling_is_nearest_and_clipped():
    maps = np.arange(2 * 3 * 5, dtype=float).reshape(2, 3, 5)
    q = np.array([[1.5, 1.5], [9.4, 5.6], [100.0, -20.0]])
    v = CELLS.sample(maps, q)
    assert v.shape == (3, 2)
    np.testing.assert_array_equal(v[:, 0], [maps[0, 0, 0], maps[0, 1, 2], maps[0, 0, 4]])


def test_cell_mask_to_input_matches_the_point_map():
    """An input pixel is in the mask exactly when its nearest cell is."""
    box = Letterbox(400, 240, (64, 96))
    rng = np.random.default_rng(1)
    mask = (rng.random((16, 24)) > 0.5).astype(np.uint8)
    full = box.cell_mask_to_input(mask)
    ys, xs = np.mgrid[0:240:7, 0:400:7]
    q = box.to_processing(np.stack([xs.ravel(), ys.ravel()], 1).astype(float))
    cx, cy = CELLS.nearest(q, mask.shape)
    c = CELLS.to_cell(q)
    away = (np.abs(c - np.round(c)) < 0.45).all(1)  # not on a cell border, where rounding may go either way
    assert np.array_equal(full[ys.ravel(), xs.ravel()][away], mask[cy, cx].astype(bool)[away])
