"""Progress on long work: a tqdm bar on a terminal, one line per stage in a log.

A bar redrawn with carriage returns fills a log file (CI, ``make run > log 2>&1``) with thousands
of partial lines. :func:`progress_bar` draws the bar only where standard error is a terminal;
elsewhere it prints one line when the stage ends: ``detect: 480 img in 21.3 s``.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator


class LogLine:
    """The bar's interface for a log: counts quietly, prints ``desc: N unit in T s`` once on close
    (or at the end of the iteration). ``set_postfix`` values are kept and printed with it."""

    def __init__(self, iterable: Iterable | None = None, desc: str = "", total: int | None = None, unit: str = "it", initial: int = 0):
        self.iterable, self.desc, self.total, self.unit = iterable, desc, total, unit
        self.n, self.start, self.closed, self.postfix = initial, time.perf_counter(), False, {}

    def __iter__(self) -> Iterator:
        for item in self.iterable or ():
            yield item
            self.n += 1
        self.close()

    def __enter__(self) -> LogLine:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def update(self, n: int = 1) -> None:
        self.n += n

    def set_postfix(self, **values) -> None:
        self.postfix = values

    def write(self, line: str) -> None:
        print(line, file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        extra = "".join(f", {k} {v}" for k, v in self.postfix.items())
        print(f"{self.desc}: {self.n} {self.unit} in {time.perf_counter() - self.start:.1f} s{extra}", file=sys.stderr, flush=True)


class _Silent(LogLine):
    def close(self) -> None:
        self.closed = True


def progress_bar(
    iterable: Iterable | None = None, *, desc: str, total: int | None = None, unit: str = "it", enabled: bool = True, initial: int = 0
):
    """A tqdm bar over ``iterable`` where standard error is a terminal; a :class:`LogLine` where it
    is not; nothing at all where ``enabled`` is False. All three iterate, ``update``,
    ``set_postfix``, ``write`` and ``close`` alike."""
    if not enabled:
        return _Silent(iterable, desc, total, unit, initial)
    if not sys.stderr.isatty():
        return LogLine(iterable, desc, total, unit, initial)
    from tqdm import tqdm

    return tqdm(iterable, desc=desc, total=total, unit=unit, initial=initial, dynamic_ncols=True)
