"""Live sessions one after another in one process stay flat (issue 29): the C allocator's
mmap threshold is fixed, so a large block freed by a session goes back to the system instead of
raising the threshold and leaving the next session's large blocks on the heap."""

import ctypes
from pathlib import Path

import numpy as np
import pytest

from wearable_gaze.live.allocator import MMAP_THRESHOLD_BYTES, bound_heap, release_free_memory


class _MallInfo2(ctypes.Structure):
    _fields_ = [(n, ctypes.c_size_t) for n in ("arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks",
                                                 "fsmblks", "uordblks", "fordblks", "keepcost")]


def _mapped_bytes() -> int:
    """Bytes in blocks glibc mapped on their own (``mallinfo2().hblkhd``)."""
    f = ctypes.CDLL(None).mallinfo2
    f.restype = _MallInfo2
    return f().hblkhd


def _check_in_this_process() -> None:
    big = np.ones(8 * 2**20 // 8)            # 8 MB, mapped; freeing it raises glibc's own threshold to 8 MB
    del big
    assert bound_heap()
    before = _mapped_bytes()
    block = np.ones(4 * MMAP_THRESHOLD_BYTES // 8)       # 1 MB: under the raised threshold, over the fixed one
    assert _mapped_bytes() - before >= block.nbytes
    del block
    assert _mapped_bytes() <= before + MMAP_THRESHOLD_BYTES      # and gone back to the system when freed
    release_free_memory()                   # callable any time; True or False (nothing to hand back)


def test_a_large_block_after_a_larger_one_freed_is_mapped_on_its_own():
    """In a fresh interpreter: the allocator's state is process-wide, and a test run's other
    threads (and earlier sessions' settings) would move the counts."""
    import subprocess
    import sys

    try:
        _mapped_bytes()
    except AttributeError:
        pytest.skip("not glibc (no mallinfo2): the allocator is left as it is")
    code = "import sys; sys.path[:0] = sys.argv[1:]; import test_live_allocator as t; t._check_in_this_process()"
    here = str(Path(__file__).resolve().parent)
    run = subprocess.run([sys.executable, "-c", code, here, str(Path(here).parent)], capture_output=True, text=True,
                         timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
