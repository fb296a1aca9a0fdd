"""The renderer's settings: what a rendered sample may look like (``render:`` in a training config)."""

from __future__ import annotations

from dataclasses import dataclass, field

from cotrain.geometry import cameras
from cotrain.targets import TargetConfig


@dataclass
class RenderConfig:
    height: int = 216  # output image height, pixels
    width: int = 384  # output image width, pixels
    models: list[str] = field(default_factory=lambda: list(cameras.MODELS))  # camera families drawn
    model_weights: list[float] = field(default_factory=lambda: [0.4, 0.2, 0.2, 0.2])  # their probabilities
    fov_range: tuple[float, float] = (150.0, 250.0)  # FoV (deg) drawn uniformly
    radius_range: tuple[float, float] = (0.8, 1.9)  # image-circle radius / (min(h, w) / 2); >1 is cropped
    principal_jitter: float = 0.04  # principal-point offset, fraction of min(h, w)
    aspect_jitter: float = 0.02  # fy / fx - 1 drawn in +-this
    kb4_k_scale: float = 1.0  # scale of the random k1..k4 of kb4 cameras (0 = the paper's f-theta model)
    p_no_target: float = 0.03  # probability of an image without the target (negatives)
    distance_range: tuple[float, float] = (0.12, 0.9)  # board-centre distance, metres
    max_tilt_deg: float = 70.0  # board tilt away from facing the camera
    offaxis_margin_deg: float = 12.0  # board centres drawn up to FoV/2 + this (partial views)
    offaxis_min_deg: float = 0.0  # ... and at least this far off-axis (a row of boards at the rim)
    supersample: int = 1  # extra supersampling on top of the analytic area filter
    p_blur: float = 0.5  # probability of defocus blur
    max_blur_sigma: float = 1.2  # defocus sigma (pixels) upper bound
    p_motion: float = 0.15  # probability of motion blur
    motion_kernel: tuple[int, int] = (5, 5)  # motion-blur length (pixels, odd) drawn in this range
    motion_direction: tuple[float, float] = (-1.0, 1.0)  # kornia's weighting along the blur (0: even, the label at mid-exposure)
    exposure_range: tuple[float, float] = (0.6, 1.4)  # exposure gain (over 1 clips the whites)
    gamma_range: tuple[float, float] = (0.7, 1.4)  # gamma after the exposure
    black_range: tuple[float, float] = (0.02, 0.2)  # reflectance of the printed black
    white_range: tuple[float, float] = (0.6, 1.0)  # reflectance of the printed white (grey on a dull print)
    vignette_range: tuple[float, float] = (0.0, 0.6)  # darkening at the image circle's rim (share of the centre)
    p_glare: float = 0.0  # probability of a specular highlight on the print (0: no draws, renders as before)
    glare_strength: tuple[float, float] = (0.4, 1.5)  # its peak, added reflectance (the print's white is white_range)
    glare_size: tuple[float, float] = (0.08, 0.3)  # its Gaussian sigma, share of the board's extent along each axis
    noise_range: tuple[float, float] = (0.0, 0.04)  # Gaussian read-noise sigma (intensity units)
    p_jpeg: float = 0.3  # probability of JPEG compression
    p_occluder: float = 0.3  # probability of 1-3 occluders in front of the board
    p_distractor: float = 0.5  # probability of checker-like distractors in the background
    n_shapes: int = 8  # rectangles and lines in the background
    min_square_px: float = 3.0  # learnability is 0 below this projected square size (pixels)
    good_square_px: float = 7.0  # learnability is 1 (size term) above this
    border_px: float = 2.0  # corners closer than this to the frame or circle edge are not visible
    target: TargetConfig = field(default_factory=TargetConfig)  # the calibration target
