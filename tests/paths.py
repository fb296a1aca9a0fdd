"""Paths the tests share: the repository root, its configs and ../shared beside the clone."""

from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TINY = ROOT / "configs" / "tiny.yaml"
SHARED = ROOT.parent / "shared"
