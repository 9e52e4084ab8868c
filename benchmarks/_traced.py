"""One traced import for the import benchmarks: a device module's reader run into a new
session, timed, with the peak of Python's allocations (tracemalloc)."""

import time
import tracemalloc
from pathlib import Path

from wearable_gaze.formats.devices.common import ImportOptions, SessionImport


def traced_import(module, src: Path, out: Path, options: ImportOptions | None = None):
    """(seconds, peak traced bytes, the finished ``SessionImport``) of ``module.read_recording``
    on ``src`` into the new session folder ``out``."""
    tracemalloc.start()
    t0 = time.perf_counter()
    with SessionImport(out, module.NAME, src) as imp:
        module.read_recording(src, imp, options or ImportOptions())
    dt = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return dt, peak, imp
