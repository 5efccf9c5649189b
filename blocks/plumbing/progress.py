"""Progress displays for long runs, on a terminal and in a log.

Long functions take ``progress``, a callable ``progress(stage, fraction)``:
``stage`` names what is being done and ``fraction`` (0..1) how much of that
stage is done.  :class:`StageProgress` shows those calls; :func:`count_progress`
gives the counter a batch of runs reports to (finished runs of a total).

On a terminal the bars are drawn by tqdm (redrawn at most every 0.1 s); the
time at the end of a bar is how long that step has taken so far ("step time").
On anything else -- a log file, a pipe, a CI console -- nothing is redrawn: a
stage that runs for more than :data:`LOG_EVERY_S` writes a line with how far it
has got whenever it advances after that long a silence, and every stage writes
one line when it ends, with how long it took; a counter writes one line per
tenth of the runs.
"""
from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from typing import Protocol

from tqdm import tqdm

__all__ = ["ProgressCallback", "Counter", "StageProgress", "CountProgress", "count_progress", "is_terminal"]

ProgressCallback = Callable[[str, float], None]

# Resolution of a stage bar: fractions are shown to 0.1 %.
_STEPS = 1000
_STAGE_FORMAT = "{desc:<34} {percentage:5.1f}%|{bar:30}| step time {elapsed_s:.1f} s"   # this stage's own time
#: In a log, a stage that advances after this long (s) without a line writes how far it has got.
LOG_EVERY_S = 2.0


def is_terminal(stream) -> bool:
    """Whether ``stream`` is an interactive terminal (then bars are redrawn in place)."""
    isatty = getattr(stream, "isatty", None)
    return bool(isatty and isatty())


class StageProgress:
    """A ``progress(stage, fraction)`` display: one bar per stage on a terminal, one line per stage elsewhere.

    A stage ends when the next one starts or the display is closed; it then
    shows how long it took (s).  Fractions are clipped to 0..1 and never go
    back within a stage.

    Parameters
    ----------
    stream : file, optional
        Where to write (default: standard error).
    enabled : bool
        False: show nothing.

    Examples
    --------
    >>> import io
    >>> log = io.StringIO()
    >>> with StageProgress(log) as progress:
    ...     progress("simulating", 0.5)
    ...     progress("simulating", 1.0)
    ...     progress("writing figures", 0.0)
    >>> [line.split(", took")[0] for line in log.getvalue().splitlines()]
    ['simulating: done', 'writing figures: done']
    """

    def __init__(self, stream=None, enabled: bool = True) -> None:
        self.stream = sys.stderr if stream is None else stream
        self.enabled = enabled
        self.terminal = is_terminal(self.stream)
        self.stage: str | None = None
        self.fraction = 0.0
        self._started = 0.0
        self._last_line = 0.0
        self._bar: tqdm | None = None

    def __call__(self, stage: str, fraction: float) -> None:
        if not self.enabled:
            return
        if stage != self.stage:
            self._end()
            self._begin(stage)
        fraction = float(fraction)
        before = self.fraction
        self.fraction = max(self.fraction, min(1.0, fraction) if math.isfinite(fraction) else 0.0)
        if self._bar is not None:
            self._bar.update(round(_STEPS * self.fraction) - self._bar.n)
        elif before < self.fraction < 1.0:
            now = time.monotonic()
            if now - self._last_line >= LOG_EVERY_S:
                self._last_line = now
                self.stream.write(f"{self.stage}: {100 * self.fraction:.0f}% after {now - self._started:.1f} s\n")
                self.stream.flush()

    def close(self, failed: bool = False) -> None:
        """End the current stage (``failed``: it did not complete)."""
        self._end(failed)

    def __enter__(self) -> StageProgress:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close(failed=exc_type is not None)

    def _begin(self, stage: str) -> None:
        self.stage, self.fraction, self._started = stage, 0.0, time.monotonic()
        self._last_line = self._started
        if self.terminal:
            self._bar = tqdm(total=_STEPS, desc=stage, file=self.stream, leave=True, bar_format=_STAGE_FORMAT,
                             mininterval=0.1)

    def _end(self, failed: bool = False) -> None:
        if self.stage is None:
            return
        if self._bar is not None:
            if not failed:
                self._bar.update(_STEPS - self._bar.n)       # a stage that ended is done
            self._bar.close()
            self._bar = None
        else:
            seconds = time.monotonic() - self._started
            outcome = "stopped after" if failed else "done, took"
            self.stream.write(f"{self.stage}: {outcome} {seconds:.1f} s\n")
            self.stream.flush()
        self.stage = None


class Counter(Protocol):
    """What a batch of runs reports to: ``update(n)`` runs finished, ``close()`` at the end."""

    def update(self, n: int) -> None: ...

    def close(self) -> None: ...


class CountProgress:
    """Finished runs of a total: a tqdm bar on a terminal, a line per tenth of the total elsewhere.

    Parameters
    ----------
    total : int
        Runs in all.
    done : int
        Runs already finished before this display started (for example found in a results file).
    stream : file, optional
        Default: standard error.
    enabled : bool
        False: show nothing.
    label : str
        What is counted, shown first on the line.
    """

    def __init__(self, total: int, done: int = 0, stream=None, enabled: bool = True, label: str = "sweep") -> None:
        self.total, self.done, self.start_done = int(total), int(done), int(done)
        self.stream = sys.stderr if stream is None else stream
        self.enabled, self.label = enabled, label
        self.started = time.monotonic()
        self._bar = None
        self._last_tenth = -1
        if enabled and is_terminal(self.stream):
            self._bar = tqdm(total=self.total, initial=self.done, desc=label, unit="run", file=self.stream,
                             mininterval=0.1)
        else:
            self._line()

    def update(self, n: int) -> None:
        """``n`` more runs finished."""
        self.done += int(n)
        if self._bar is not None:
            self._bar.update(int(n))
        else:
            self._line()

    def close(self) -> None:
        """End the display."""
        if self._bar is not None:
            self._bar.close()

    def _line(self) -> None:
        if not self.enabled:
            return
        frac = self.done / self.total if self.total else 1.0
        if int(10 * frac) == self._last_tenth:
            return
        self._last_tenth = int(10 * frac)
        elapsed = time.monotonic() - self.started
        rate = (self.done - self.start_done) / elapsed if elapsed > 0 else 0.0
        left = f"about {(self.total - self.done) / rate:.0f} s left" if rate > 0 else "time left unknown"
        self.stream.write(f"{self.label}: {self.done}/{self.total} runs {100 * frac:3.0f}%, {elapsed:.1f} s so far, "
                          f"{left}\n")
        self.stream.flush()


class _FractionCounter:
    """A counter that reports ``progress(label, done / total)`` to a callback."""

    def __init__(self, progress: ProgressCallback, total: int, done: int, label: str) -> None:
        self.progress, self.total, self.done, self.label = progress, int(total), int(done), label
        self._report()

    def update(self, n: int) -> None:
        self.done += int(n)
        self._report()

    def close(self) -> None:
        pass

    def _report(self) -> None:
        self.progress(self.label, self.done / self.total if self.total else 1.0)


def count_progress(progress: bool | ProgressCallback | None, total: int, done: int = 0,
                   label: str = "sweep") -> Counter:
    """The counter for a function's ``progress`` argument.

    Parameters
    ----------
    progress : bool, callable or None
        True: a :class:`CountProgress` on standard error; False or None:
        nothing; a callable: called as ``progress(label, done / total)`` at the
        start and after every update.
    total, done : int
        Runs in all, and already finished.
    label : str
    """
    if callable(progress):
        return _FractionCounter(progress, total, done, label)
    return CountProgress(total, done, enabled=bool(progress), label=label)
