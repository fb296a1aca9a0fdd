"""Detection evaluation: per-FoV recall and error against OpenCV, grid-pass tuning, identifiability."""

DETECTORS = ["learned", "learned_slots", "learned_slots_polish", "opencv_sb", "opencv_classic"]  # table order
DEFAULT_DETECTORS = ["learned", "learned_slots", "opencv_sb", "opencv_classic"]  # run when none are named
