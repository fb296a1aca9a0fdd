"""Synthetic checkerboard images with exact corner positions, for the grid pass's tests."""

import numpy as np

from cotrain.targets import Checkerboard

BOARD = Checkerboard()  # the default 10 x 7 board
NX, NY = BOARD.nx, BOARD.ny  # its inner corners


def board_image(sq: int = 30, org: tuple[int, int] = (40, 36), size: tuple[int, int] = (200, 170)) -> tuple[np.ndarray, np.ndarray]:
    """A fronto-parallel 10 x 7 checkerboard (square (0, 0) black) with its white margin on grey
    background, cut by the image: returns the image and every corner id's pixel position."""
    ss = 4
    H, W = size[1] * ss, size[0] * ss
    ys, xs = (np.mgrid[0:H, 0:W] + 0.5) / ss - 0.5
    u, v = (xs - org[0]) / sq, (ys - org[1]) / sq  # board coordinates in squares
    img = np.full((H, W), 0.45)
    on_board = (u > -0.5) & (u < 10.5) & (v > -0.5) & (v < 7.5)
    img[on_board] = 0.92
    sqs = (u >= 0) & (u < 10) & (v >= 0) & (v < 7)
    black = (np.floor(u).astype(int) + np.floor(v).astype(int)) % 2 == 0
    img[sqs & black] = 0.08
    img = img.reshape(size[1], ss, size[0], ss).mean((1, 3)).astype(np.float32)
    ids = np.arange(NX * NY)
    q = np.stack([org[0] + (ids % NX + 1) * sq, org[1] + (ids // NX + 1) * sq], 1).astype(float)
    return img, q


def warped_board_image(to_board, to_pixels, size: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """A 10 x 7 checkerboard (square (0, 0) black, white margin of half a square, grey around)
    drawn through a warp: ``to_board(x, y) -> (u, v)`` maps pixels to board columns and rows (in
    squares), ``to_pixels(u, v) -> (x, y)`` is its inverse (arrays in, arrays out). Squares may grow
    or shrink fast across the board, as near a fisheye's rim. Returns the image and every corner
    id's pixel position."""
    ss = 4
    H, W = size[1] * ss, size[0] * ss
    ys, xs = (np.mgrid[0:H, 0:W] + 0.5) / ss - 0.5
    u, v = to_board(xs, ys)
    img = np.full((H, W), 0.45)
    img[(u > -0.5) & (u < 10.5) & (v > -0.5) & (v < 7.5)] = 0.92
    sqs = (u >= 0) & (u < 10) & (v >= 0) & (v < 7)
    black = (np.floor(u).astype(int) + np.floor(v).astype(int)) % 2 == 0
    img[sqs & black] = 0.08
    img = img.reshape(size[1], ss, size[0], ss).mean((1, 3)).astype(np.float32)
    ids = np.arange(NX * NY)
    return img, np.stack(to_pixels(ids % NX + 1.0, ids // NX + 1.0), 1)
