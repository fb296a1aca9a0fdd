from cotrain.targets.checkerboard import Checkerboard, TargetConfig

__all__ = ["Checkerboard", "TargetConfig"]
