"""Pin a benchmark to one core with single-threaded BLAS and OpenCV. Import it first.

``BENCH_CORES=2`` (environment) allows two cores instead, for the measurements that say so.
"""

import os

CORES = int(os.environ.get("BENCH_CORES", "1"))
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
try:
    os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[:CORES]))
except (AttributeError, OSError):
    pass
try:
    import cv2

    cv2.setNumThreads(1)
except ImportError:  # pragma: no cover
    pass
