"""Progress that a log shows (issue 25): off a terminal a long step prints a line at least every
``WEARABLE_GAZE_PROGRESS_S`` seconds, also while one blocking call runs (pycolmap's matching, a
map's bundle adjustment); on a terminal the bar's clock keeps running; map building reports its
bundle adjustments' steps through its progress callback. The interval is a fraction of a second
here (5 s by default); tests/conftest.py turns the lines off for every other test."""

import io
import time

import numpy as np
import pytest

import wearable_gaze.progress as progress_module
from wearable_gaze.progress import LINE_INTERVAL_S, heartbeat, progress_bar, staged

INTERVAL = 0.2


class Log(io.StringIO):
    """A stream that is not a terminal and keeps when each line was written."""

    def __init__(self):
        super().__init__()
        self.times = []

    def write(self, text):
        self.times += [time.monotonic()] * text.count("\n")
        return super().write(text)


class Tty(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def every(monkeypatch):
    monkeypatch.setenv("WEARABLE_GAZE_PROGRESS_S", str(INTERVAL))
    return INTERVAL


def _gaps(times, t0) -> list:
    return np.diff([t0, *times]).tolist()


def test_the_default_interval_keeps_to_the_rule(monkeypatch):
    monkeypatch.delenv("WEARABLE_GAZE_PROGRESS_S", raising=False)
    assert 0 < progress_module.line_interval_s() == LINE_INTERVAL_S <= 10.0


def test_off_a_terminal_a_blocking_call_prints_a_line_every_interval(every):
    """A step that reports nothing for 1.5 s (one blocking call) printed nothing in a log until it
    ended; now a line at least every interval (a quarter of it late at most), and one at the end
    saying how it ended."""
    log = Log()
    t0 = time.monotonic()
    with heartbeat("mapping", log):
        time.sleep(1.5)
    lines = log.getvalue().splitlines()
    assert len(lines) >= 5 and all(ln.startswith("mapping: still running, ") for ln in lines[:-1]), lines
    assert lines[-1].startswith("mapping: done, "), lines
    assert max(_gaps(log.times, t0)) < 1.25 * every + 0.1, _gaps(log.times, t0)
    failed = Log()
    with pytest.raises(ValueError), heartbeat("mapping", failed):
        time.sleep(0.5)
        raise ValueError("no reconstruction")
    assert failed.getvalue().splitlines()[-1].startswith("mapping: stopped, ")       # not "done"


def test_off_a_terminal_lines_say_how_far_and_which_stage(every):
    log = Log()
    with progress_bar("markerless map", 1, log) as cb:
        for k in range(4):
            staged(cb, "features")(k + 1, 8)
        time.sleep(0.5)
        staged(cb, "matching")(0, 0)
        time.sleep(0.5)
        cb(3, 5)                                            # a callback without a stage clears it
        time.sleep(0.5)
    text = log.getvalue()
    assert "markerless map: features: 4/8 (50%), " in text
    assert "markerless map: matching: still running, " in text
    assert "markerless map: 3/5 (60%), " in text
    quick = Log()                                           # a step shorter than the interval: nothing
    with progress_bar("quick", 3, quick) as cb:
        cb(3, 3)
    assert quick.getvalue() == ""

    def plain(done, total):                                 # a callback that shows no stage gets none
        pass
    assert staged(plain, "x") is plain and staged(None, "x") is None


def test_on_a_terminal_the_bar_is_redrawn_while_a_blocking_call_runs(monkeypatch):
    """tqdm redraws only when a step is reported: through a 1.3 s call the bar stood still, its clock
    too. Now it is redrawn every ``REFRESH_S``, with the stage named."""
    monkeypatch.setattr(progress_module, "REFRESH_S", 0.05)
    tty = Tty()
    with progress_bar("markerless map", 1, tty) as cb:
        staged(cb, "matching")(0, 0)
        drawn = tty.getvalue().count("\r")
        time.sleep(1.3)
        assert tty.getvalue().count("\r") >= drawn + 10
        assert "markerless map: matching" in tty.getvalue().rsplit("\r", 1)[-1]
        assert "00:01" in tty.getvalue()                      # the clock ran
