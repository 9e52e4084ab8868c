"""Pin a benchmark to one core with single-threaded BLAS and OpenCV. Import it first."""

import os

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")
try:
    os.sched_setaffinity(0, {sorted(os.sched_getaffinity(0))[0]})
except (AttributeError, OSError):
    pass
try:
    import cv2

    cv2.setNumThreads(1)
except ImportError:  # pragma: no cover
    pass
