"""The degradations the grid-tuning script applies to rendered frames (another camera or renderer)."""

import cv2
import numpy as np
import pytest

from calib_eval.detection.tuning import degrade


def _frame() -> np.ndarray:
    g = np.indices((120, 160)).sum(0) // 20 % 2 * 0.8 + 0.1  # a checker of 20 px squares
    return g.astype(np.float32)


def test_degradations_keep_the_frame_and_change_it_as_stated():
    img = _frame()
    assert degrade(img, "none") is img
    jpg = degrade(img, "jpeg")
    assert jpg.shape == img.shape and jpg.dtype == np.float32 and 0 <= jpg.min() and jpg.max() <= 1
    # gamma 0.8 brightens the dark squares: 0.1 -> 0.1 ** 0.8 = 0.158 (JPEG keeps flat areas)
    assert np.median(jpg[img < 0.5]) == pytest.approx(0.1**0.8, abs=0.01)
    blur = degrade(img, "blur", seed=3)
    ref = cv2.GaussianBlur(img, (0, 0), 1.5)
    resid = blur - ref
    assert abs(resid.std() - 4 / 255) < 0.003 and abs(resid.mean()) < 0.002  # the added noise
    np.testing.assert_array_equal(blur, degrade(img, "blur", seed=3))
    with pytest.raises(ValueError, match="degradation"):
        degrade(img, "fog")


def test_grid_overrides_take_the_fields_type_and_refuse_unknown_keys():
    from calib_eval.detection.tuning import grid_overrides

    got = grid_overrides(["offboard_penalty=15", "max_seeds=20"])
    assert got == {"offboard_penalty": 15.0, "max_seeds": 20}
    # A switch reads true / false, in any case ("False" is not bool("False")).
    assert grid_overrides(["completion=False", "half_resolution=true"]) == {"completion": False, "half_resolution": True}
    with pytest.raises(ValueError, match="not a valid bool"):
        grid_overrides(["completion=0.5"])
    assert isinstance(got["max_seeds"], int) and isinstance(got["offboard_penalty"], float)
    with pytest.raises(ValueError, match="KEY=VALUE"):
        grid_overrides(["no_such_field=1"])
    with pytest.raises(ValueError, match="KEY=VALUE"):
        grid_overrides(["offboard_penalty"])
    with pytest.raises(ValueError, match="not a valid float"):
        grid_overrides(["offboard_penalty=high"])
    with pytest.raises(ValueError, match="not a valid int"):
        grid_overrides(["max_seeds=2.5"])
    with pytest.raises(ValueError, match="KEY=VALUE"):
        grid_overrides(["min_margin=10"])  # the table sweeps it
    with pytest.raises(ValueError, match="KEY=VALUE"):
        grid_overrides(["votes_alone=False"])  # the table turns it on


def test_the_table_scores_every_placement():
    """The threshold the table sweeps, and the votes alone turned on, let every placement through,
    however few nats ahead and whatever the geometry says (none at all included)."""
    import dataclasses

    from calib_eval.detection.tuning import SWEPT
    from cotrain.detect.grid_config import GridConfig
    from cotrain.detect.grid_pass import placement_is_sure

    cfg = dataclasses.replace(GridConfig(), **SWEPT)
    for margin, geometry in ((0.0, 0.0), (0.5, -10.0), (3.0, 5.0), (1.0, 20.0)):
        assert placement_is_sure(margin, geometry, cfg)
