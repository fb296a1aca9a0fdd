"""``make run``: the main job, ``cotrain pipeline`` on the embedded default (configs/pipeline.yaml)."""

from __future__ import annotations

import sys

from cotrain.cli import run


def main() -> int:
    return run(["pipeline", "--config", "configs/pipeline.yaml", *sys.argv[1:]])


if __name__ == "__main__":
    sys.exit(main())
