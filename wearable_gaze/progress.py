"""Progress bars for the CLI (the libraries report progress through callbacks)."""

from __future__ import annotations

import sys
from contextlib import contextmanager


@contextmanager
def progress_bar(description: str, total: int):
    """Yield a ``progress(done, total)`` callback drawing a bar on stderr (quiet when not a TTY
    and in CI logs, where it prints one line at the end)."""
    from tqdm import tqdm  # noqa: PLC0415

    bar = tqdm(total=total, desc=description, unit="step", file=sys.stderr, leave=False,
               disable=not sys.stderr.isatty())
    state = {"done": 0}

    def callback(done: int, total_: int):
        if total_ != bar.total:             # a new total is drawn at once, not at the next step
            bar.total = total_
            bar.refresh()
        bar.update(done - state["done"])
        state["done"] = done

    try:
        yield callback
    finally:
        bar.close()
