"""The threading policy: how many threads each thread pool of a cellsight process may use, and
how its idle threads wait.

The pools: numba's (the predictor's kernel on large scenes,
:data:`~cellsight.occlusion.forest.PARALLEL_MIN_POINTS`), OpenCV's, the BLAS's under NumPy and
SciPy (through threadpoolctl), and Mesa's software OpenGL renderer (llvmpipe,
``LP_NUM_THREADS``, read when the first OpenGL context is made).

- **How many:** a process uses the cores it may run on (its CPU affinity); a sweep's jobs
  share them, each ``cores // jobs`` of them, at least one (:func:`share`).
- **How they wait:** idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE``). numba's
  threading layer stays its own choice (OpenMP, GNU libgomp, where it is installed), whose
  threads by default spin after each parallel region: beside other work the spinning took
  the cores from the work, and the predictor's kernel ran 60-100x slower. Measured on this
  kind of 2-core machine (the kernel on 5,552 query points, ms): spinning 0.46 quiet and
  15.9 beside a busy loop per core; sleeping 0.89 and 1.63; numba's ``workqueue`` layer 0.84
  and 1.45 (and only 1.5x serial where OpenMP gives 2x on 55,520 points); serial 1.0 and
  1.9.
- **Where:** no parallel region where the work is smaller than waking a thread (the
  predictor's kernel runs serially below its threshold).

The answers do not depend on the number of threads. :func:`apply` sets the policy in this
process (the CLI does it first thing; a sweep's workers in their initializer; a program using
the library calls it itself, and gets the sleeping OpenMP threads on importing cellsight,
:func:`prefer_sleeping_threads`) and :func:`environment` gives the variables a child process
needs before it starts.
"""

from __future__ import annotations

import os

_VARIABLES = ("OMP_WAIT_POLICY", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS",
              "LP_NUM_THREADS")
_USER_SET = frozenset(name for name in _VARIABLES if name in os.environ)
"""The policy's variables the user set before cellsight was imported: theirs are kept."""


def cores() -> int:
    """The cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def share(jobs: int) -> int:
    """Threads per job when ``jobs`` jobs run at once on this process's cores (at least 1)."""
    return max(1, cores() // max(1, int(jobs)))


def environment(threads: int) -> dict[str, str]:
    """The environment variables of the policy for a process of ``threads`` threads, read by
    the libraries when they load (set them before a child process starts), except those the
    user set."""
    n = str(max(1, int(threads)))
    values = dict(zip(_VARIABLES, ("PASSIVE", n, n, n, n), strict=True))
    return {name: value for name, value in values.items() if name not in _USER_SET}


def prefer_sleeping_threads() -> None:
    """Idle OpenMP threads sleep (``OMP_WAIT_POLICY=PASSIVE``) unless the user chose: set
    when cellsight is imported, before numba starts its threads, so that a program using the
    library without :func:`apply` does not get spinning threads either. Nothing else
    changes."""
    if "OMP_WAIT_POLICY" not in _USER_SET:
        os.environ["OMP_WAIT_POLICY"] = "PASSIVE"


def apply(threads: int | None = None) -> int:
    """Set the policy in this process for ``threads`` threads per pool (default: its cores);
    returns that number. Environment variables the user set are kept; the libraries already
    loaded are set directly (numba, OpenCV, the BLAS)."""
    import cv2
    import numba
    from threadpoolctl import threadpool_limits

    n = max(1, int(threads if threads is not None else cores()))
    os.environ.update(environment(n))
    numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))
    cv2.setNumThreads(n)
    threadpool_limits(n)
    return n
