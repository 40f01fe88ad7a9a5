"""Optional numba: ``jit`` compiles with numba when it is installed (and HSIO_NO_NUMBA is unset),
and returns the plain Python function otherwise. Both give the same numbers: the kernels use only
scalar arithmetic in a fixed order, no fast-math."""

from __future__ import annotations

import os

try:  # pragma: no cover - depends on the environment
    import numba as _numba
except ImportError:  # pragma: no cover
    _numba = None

HAVE_NUMBA = _numba is not None


def numba_enabled() -> bool:
    return HAVE_NUMBA and not os.environ.get("HSIO_NO_NUMBA")


def jit(fn):
    """``fn`` compiled in nopython mode, or ``fn`` itself; the Python original stays at ``.py_func``."""
    if not HAVE_NUMBA:
        fn.py_func = fn
        return fn
    return _numba.njit(cache=False)(fn)


def pick(fn, use_numba: bool | None = None):
    """The compiled or the Python version of a ``jit`` function."""
    if use_numba is None:
        use_numba = numba_enabled()
    return fn if (use_numba and HAVE_NUMBA) else fn.py_func


def helper(fn):
    """A function called from ``jit`` functions: compiled inline with them under numba, and a plain
    Python function when they run as Python (so the Python loop never calls into numba)."""
    if not HAVE_NUMBA:
        return fn
    from numba.extending import register_jitable

    return register_jitable(fn)
