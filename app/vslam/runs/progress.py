"""Progress of a run on stderr: a live bar on a terminal, plain throttled lines elsewhere (CI logs).

Without a terminal a bar cannot redraw, so nothing would show until the end. There, one line is printed
whenever another 5 % of the frames is done or 10 s have passed since the last line, whichever comes first:

    progress kitti-00: frame 120/300 (40 %), 23.1 frames/s, ETA 0:08

stdout is never touched: it holds the results, for machines to parse.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

PERCENT_STEP = 5.0
SECONDS_STEP = 10.0

Advance = Callable[[], None]


def eta(seconds: float) -> str:
    seconds = max(int(round(seconds)), 0)
    hours, rest = divmod(seconds, 3600)
    minutes, secs = divmod(rest, 60)
    return f"{hours}:{minutes:02d}:{secs:02d}" if hours else f"{minutes}:{secs:02d}"


class PlainProgress:
    """Counts frames and prints a line every `PERCENT_STEP` % or `SECONDS_STEP` s (whichever first)."""

    def __init__(self, name: str, total: int, write: Callable[[str], None],
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.name, self.total, self._write, self._clock = name, total, write, clock
        self.done = 0
        self._start = self._last_time = clock()
        self._last_percent = 0.0

    def advance(self) -> None:
        self.done += 1
        now = self._clock()
        percent = 100.0 * self.done / self.total if self.total else 100.0
        due = percent >= self._last_percent + PERCENT_STEP or now - self._last_time >= SECONDS_STEP
        if due or self.done == self.total:
            self._last_percent = percent - percent % PERCENT_STEP  # next line at the next 5 % mark
            self._last_time = now
            self._write(self.line(now))

    def line(self, now: float) -> str:
        elapsed = now - self._start
        fps = self.done / elapsed if elapsed > 0 else float("nan")
        text = f"progress {self.name}: frame {self.done}/{self.total}"
        if self.total:
            text += f" ({100.0 * self.done / self.total:.0f} %)"
        text += f", {fps:.1f} frames/s"
        if self.total and fps > 0:
            text += f", ETA {eta((self.total - self.done) / fps)}"
        return text


@contextmanager
def progress(console: Console, name: str, total: int) -> Iterator[Advance]:
    """A function to call once per frame: a Rich bar when `console` is a terminal, else plain lines on it."""
    if console.is_terminal:
        columns = (TextColumn("{task.description}", markup=False), BarColumn(), MofNCompleteColumn(),
                   TimeRemainingColumn())
        with Progress(*columns, console=console, transient=True) as bar:
            task = bar.add_task(name, total=total)
            yield lambda: bar.advance(task)
        return
    plain = PlainProgress(name, total, lambda line: console.print(line, highlight=False, markup=False,
                                                                   soft_wrap=True))
    yield plain.advance
