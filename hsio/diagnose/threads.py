"""One BLAS thread for the fits.

The least-squares fits take hundreds of small steps on long, thin matrices (one row per sample,
one column per parameter). Threads of the linear-algebra library gain nothing there and, on a
machine whose cores are busy, wait for each other at every step: a diagnosis then takes ten
times longer. Diagnose, the specimen diagnosis and the error budget run with one thread.

The limit is process-wide, not per thread: while it holds, every thread of the process (an
integrator's too) gets one BLAS thread. It is therefore set only around the top-level
functions `hsio diagnose` calls (:func:`hsio.diagnose.selection.diagnose`,
:func:`hsio.diagnose.specimen_fit.diagnose_specimen`, :func:`hsio.diagnose.budget.error_budget`),
which run alone, and never inside a helper that may run beside a hybrid test.
"""

from __future__ import annotations

import functools

from threadpoolctl import threadpool_limits


def one_blas_thread(fn):
    """``fn`` run with the BLAS libraries limited to one thread (restored afterwards). The limit
    holds for the whole process while ``fn`` runs: decorate top-level entry points only."""

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        with threadpool_limits(limits=1, user_api="blas"):
            return fn(*args, **kwargs)

    return wrapper
