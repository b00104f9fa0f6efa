"""Progress bars that read in a log: a tqdm bar on a terminal, plain lines elsewhere.

Piped to a file (a batch log, CI, ``make demo > log``) a tqdm bar writes a carriage-return update many times
a second; :class:`PlainProgress` writes one line every ``every`` of the total instead (step, share, the
shown values, time left), and one at the end.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterable, Iterator, Sized
from typing import Any, TextIO

from tqdm import tqdm

PLAIN_EVERY = 0.1
"""Share of the total between two plain lines."""


class PlainProgress:
    """The part of tqdm's interface the package uses (iteration, ``update``, ``set_postfix``, ``close``),
    as plain lines on ``file``."""

    def __init__(self, iterable: Iterable | None = None, total: int | None = None, desc: str = "",
                 initial: int = 0, disable: bool = False, file: TextIO | None = None, every: float = PLAIN_EVERY,
                 **_: Any) -> None:
        self.iterable = iterable
        if total is None and isinstance(iterable, Sized):
            total = len(iterable)
        self.total, self.n, self.desc, self.disable = total, initial, desc, disable
        self.file = file if file is not None else sys.stderr
        self.every = every
        self.postfix = ""
        self.started, self.start_n = time.perf_counter(), initial
        self.next_share = (initial / total + every) if total else every
        self.closed = False

    def __iter__(self) -> Iterator:
        for item in self.iterable if self.iterable is not None else ():
            yield item
            self.update(1)
        self.close()

    def set_postfix(self, values: dict[str, Any] | None = None, **more: Any) -> None:
        items = {**(values or {}), **more}
        self.postfix = ", ".join(f"{k} {v}" for k, v in items.items())

    def update(self, n: int = 1) -> None:
        self.n += n
        if self.total and self.n / self.total >= self.next_share - 1e-9 and self.n < self.total:
            self._line()
            while self.next_share <= self.n / self.total + 1e-9:
                self.next_share += self.every

    def close(self) -> None:
        if not self.closed and self.n > self.start_n:
            self._line()
        self.closed = True

    def _line(self) -> None:
        if self.disable:
            return
        done = self.n - self.start_n
        elapsed = time.perf_counter() - self.started
        where = f"{self.n}/{self.total} ({100.0 * self.n / self.total:.0f}%)" if self.total else f"{self.n}"
        left = ""
        if self.total and done > 0 and self.n < self.total:
            left = f", {elapsed / done * (self.total - self.n):.0f} s left"
        extra = f", {self.postfix}" if self.postfix else ""
        print(f"{self.desc}: {where}{extra}{left}", file=self.file, flush=True)


def progress_bar(iterable: Iterable | None = None, **kwargs: Any):
    """A tqdm bar when stderr is a terminal, :class:`PlainProgress` otherwise (same keywords)."""
    if sys.stderr.isatty():
        return tqdm(iterable, **kwargs)
    return PlainProgress(iterable, **kwargs)
