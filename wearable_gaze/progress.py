"""Progress for the CLI: a bar on a terminal, a timed line in a log (the libraries report progress
through ``progress(done, total)`` callbacks; only the application draws or prints it).

Off a terminal (a log, a pipe, a batch job) a step still running prints a line every
``line_interval_s()`` seconds, also while one long call that reports nothing runs (pycolmap's
matching, a bundle adjustment): a thread beside the step prints what was last reported and the
time taken so far. On a terminal the same thread keeps the bar's clock running.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from contextlib import contextmanager
from dataclasses import dataclass, field

log = logging.getLogger(__name__)

Progress = Callable[[int, int], None]
"""A progress callback, ``progress(done, total)``: what the steps and libraries report through."""
LINE_INTERVAL_S = 5.0
"""Off a terminal, a step still running prints a line this often, s (the rule: at least every 10 s)."""
LINE_INTERVAL_ENV = "WEARABLE_GAZE_PROGRESS_S"
"""The environment variable that sets that interval instead, s (0: no lines; the tests set it)."""
REFRESH_S = 1.0
"""On a terminal, the bar is redrawn this often while nothing reports (its clock keeps running)."""


def line_interval_s() -> float:
    """Seconds between the lines of a step running off a terminal: ``$WEARABLE_GAZE_PROGRESS_S``,
    else ``LINE_INTERVAL_S``; 0 (or less): none."""
    text = os.environ.get(LINE_INTERVAL_ENV)
    if text is None:
        return LINE_INTERVAL_S
    try:
        return float(text)
    except ValueError:
        log.warning("%s=%r is not a number of seconds; progress lines every %g s", LINE_INTERVAL_ENV, text,
                    LINE_INTERVAL_S)
        return LINE_INTERVAL_S


@dataclass
class LineClock:
    """When the last progress line was printed (``time.monotonic()``, s): shared by the steps of
    one command (``step_bars``), so that a run of short steps, each quiet, is not a long silence."""

    last: float = field(default_factory=time.monotonic)


class StepProgress:
    """The callback of ``progress_bar``: ``progress(done, total)`` like every progress callback,
    and also ``progress(done, total, stage)``, the stage (a short phrase, e.g. "matching") shown
    until the next call; ``total`` 0: a stage of unknown length (one blocking call)."""

    def __init__(self, description: str, total: int, stream, tty: bool, clock: LineClock | None = None):
        self.description, self.total, self.done, self.stage = description, total, 0, None
        self.stream, self.t0, self.lines = stream, time.monotonic(), 0
        self.clock = LineClock() if clock is None else clock
        self.lock = threading.Lock()
        self.bar = _bar(description, total, stream) if tty else None

    def __call__(self, done: int, total: int, stage: str | None = None) -> None:
        with self.lock:
            old = (self.total, self.stage)
            self.done, self.total, self.stage = done, total, stage
            if self.bar is not None:
                if (total, stage) != old:             # a new total or stage is drawn at once, not at the next step
                    self.bar.total = total if total > 0 else None
                    self.bar.set_description_str(f"{self.description}: {stage}" if stage else self.description,
                                                 refresh=False)
                    self.bar.n = done
                    self.bar.refresh()
                else:
                    self.bar.update(done - self.bar.n)

    def line(self) -> str:
        """What a log shows now: the step, its stage, how far (when known), the time so far."""
        what = f"{self.description}: {self.stage}" if self.stage else self.description
        elapsed = time.monotonic() - self.t0
        if self.total > 1 or (self.total == 1 and self.done > 0):
            return f"{what}: {self.done}/{self.total} ({100 * self.done / self.total:.0f}%), {elapsed:.0f} s"
        return f"{what}: still running, {elapsed:.0f} s"

    def tick(self, interval: float) -> None:
        """The ticking thread's turn: redraw the bar, or print a line when ``interval`` has passed."""
        with self.lock:
            if self.bar is not None:
                self.bar.refresh()
            elif interval > 0 and time.monotonic() - self.clock.last >= interval:
                self._write(self.line())
                self.clock.last, self.lines = time.monotonic(), self.lines + 1

    def close(self, failed: bool = False) -> None:
        """The step ended (``failed``: by an exception): the bar cleared, or, when the step printed
        any line, one more saying how it ended."""
        with self.lock:
            if self.bar is not None:
                self.bar.close()
            elif self.lines:
                self._write(f"{self.description}: {'stopped' if failed else 'done'}, "
                            f"{time.monotonic() - self.t0:.0f} s")

    def _write(self, line: str) -> None:
        self.stream.write(line + "\n")                # one write: not split by another thread's output
        self.stream.flush()


def _bar(description: str, total: int, stream):
    from tqdm import tqdm

    return tqdm(total=total if total > 0 else None, desc=description, unit="step", file=stream, leave=False)


@contextmanager
def progress_bar(description: str, total: int, stream=None, clock: LineClock | None = None):
    """Yield a ``StepProgress`` callback for the step ``description``: on a terminal a bar on
    ``stream`` (default stderr) that keeps its clock running; elsewhere a line every
    ``line_interval_s()`` while the step runs (counted from ``clock``'s last line, default the
    step's start), and one when it ends if it printed any."""
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    progress = StepProgress(description, total, stream, bool(isatty and isatty()), clock)
    interval = line_interval_s()
    if progress.bar is None and interval <= 0:       # no bar and no lines: nothing to tick
        yield progress
        return
    stop = threading.Event()
    period = REFRESH_S if progress.bar is not None else min(interval / 4, REFRESH_S)

    def run():
        while not stop.wait(period):
            progress.tick(interval)
    ticker = threading.Thread(target=run, name=f"progress: {description}", daemon=True)
    ticker.start()
    failed = True
    try:
        yield progress
        failed = False
    finally:
        stop.set()
        ticker.join()
        progress.close(failed)


def step_bars(stream=None):
    """A ``progress_factory`` for the steps of one command (``process``): ``name -> progress_bar``,
    the bars sharing one ``LineClock`` from now on, so that a log has a line at least every
    interval across steps too."""
    clock = LineClock()
    return lambda name: progress_bar(name, 1, stream, clock)


@contextmanager
def heartbeat(description: str, stream=None):
    """``progress_bar`` for a step of unknown length (one blocking call): off a terminal, lines
    "DESCRIPTION: still running, N s" while it runs."""
    with progress_bar(description, 0, stream) as progress:
        yield progress


def staged(progress, stage: str):
    """``progress`` as a ``progress(done, total)`` callback that also names ``stage`` when it
    can show one (a ``progress_bar``'s); any other callback (or None) is returned as it is."""
    if isinstance(progress, StepProgress):
        return lambda done, total: progress(done, total, stage)
    return progress
