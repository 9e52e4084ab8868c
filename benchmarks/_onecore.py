"""Pin a benchmark to one core with single-threaded BLAS and OpenCV. Import it first.

``BENCH_CORES=2`` (environment) allows two cores instead, for the measurements that say so;
``BENCH_FIRST_CORE=1`` starts at the second core (to run a long benchmark beside other work).
"""

import os

CORES = int(os.environ.get("BENCH_CORES", "1"))
FIRST = int(os.environ.get("BENCH_FIRST_CORE", "0"))
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
try:
    os.sched_setaffinity(0, set(sorted(os.sched_getaffinity(0))[FIRST:FIRST + CORES]))
except (AttributeError, OSError):
    pass
try:
    import cv2

    cv2.setNumThreads(1)
except ImportError:  # pragma: no cover
    pass
