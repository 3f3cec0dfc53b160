"""One BLAS thread per process, set before numpy loads.

numpy and scipy each load OpenBLAS, which starts one worker thread per core and keeps it
spinning for a while after every call. The compiled flight calls BLAS on matrices of
3 x 3 to 15 x 15 (the estimator's covariance), far below the size where a second thread
helps; the spinning thread only burns the second core: a 120 s in-process flight measured
127 ms of CPU for 64 ms of wall time with the default pool, 67 ms of CPU with one thread.
Where two of our processes share two cores (plant and autopilot, a campaign's workers, the
test suite's workers) that core is the partner's.

Each of our packages imports :mod:`heli_common` first, and ``heli_common/__init__`` calls
:func:`one_blas_thread`, so the limit is in place before numpy is imported, in every
process we start and in a user's interpreter that imports us first. A value the user has
set wins (``OPENBLAS_NUM_THREADS=2 heli-sitl ...``); once numpy is loaded the setting has
no effect (the pools are sized at load), which :func:`blas_threads_limited` tells.
"""

from __future__ import annotations

import os
import sys

__all__ = ["SINGLE_THREAD_ENV", "blas_threads_limited", "one_blas_thread"]

#: the thread pools of OpenMP, OpenBLAS, MKL and numba's parallel layer, each set to 1 (the
#: environment of a worker process: one flight a process)
SINGLE_THREAD_ENV = {
    "OMP_NUM_THREADS": "1",
    "OPENBLAS_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "NUMBA_NUM_THREADS": "1",
}
# what every process of ours limits: the BLAS pools. Not numba's: its pool serves only the
# parallel kernels (the vectorised Gymnasium env, heli_sitl.engine.batch), which are there to
# use the cores, start no thread until one runs, and are sized per call (heli_common.jit)
_BLAS_POOLS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")

_LIMITED_AT_LOAD: bool | None = None  # whether the limit was in place when first asked


def one_blas_thread() -> None:
    """Set each BLAS pool of :data:`SINGLE_THREAD_ENV` to one thread unless already set."""
    global _LIMITED_AT_LOAD
    if _LIMITED_AT_LOAD is None:
        _LIMITED_AT_LOAD = "numpy" not in sys.modules
    for k in _BLAS_POOLS:
        os.environ.setdefault(k, SINGLE_THREAD_ENV[k])


def blas_threads_limited() -> bool:
    """True if this process's BLAS was loaded with the limit (or with the user's own value):
    numpy was not yet imported when :func:`one_blas_thread` first ran."""
    return bool(_LIMITED_AT_LOAD)
