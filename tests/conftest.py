"""Shared fixtures: paths to the data beside the repository (skipped where absent), the bench
scripts as modules."""

import importlib.util
import os
import shutil
from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder {SHARED_DATA} is absent (CI and developer machines have it)")
    return SHARED_DATA


@pytest.fixture
def load_bench():
    """``load_bench("bench_soak")``: bench/bench_soak.py as a module (the bench folder is not a package)."""
    def load(name: str):
        spec = importlib.util.spec_from_file_location(name, Path(__file__).resolve().parents[1] / "bench" / f"{name}.py")
        module = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(module)
        return module
    return load


# Long tests (the 100,000-step soak) are marked slow and run only with HSIO_SLOW=1, so that a
# plain `pytest -q` stays bounded.
def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a long test; runs only when the environment sets HSIO_SLOW=1")
    _records_in_memory(config)
    _one_blas_thread()


# The tests' matrices are small and the suite shares a few cores with the emulators and servers it
# starts: BLAS thread pools only fight each other. One thread here and in every subprocess.
def _one_blas_thread() -> None:
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ.setdefault(name, "1")
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)


# Records are durable: every committed step waits for SQLite's fsync. On a disk that costs several
# milliseconds a step and dominates the suite's wall time; tests that need no power-loss safety
# keep their temporary folders in memory (/dev/shm) where it has room, the same code path with a
# cheap fsync. HSIO_TEST_TMP=disk keeps them on disk.
MEMORY_ROOT = Path("/dev/shm")
MEMORY_NEEDED = 2 << 30


def _records_in_memory(config) -> None:
    if config.option.basetemp or os.environ.get("PYTEST_DEBUG_TEMPROOT") or os.environ.get("HSIO_TEST_TMP") == "disk":
        return
    try:
        if shutil.disk_usage(MEMORY_ROOT).free < MEMORY_NEEDED or not os.access(MEMORY_ROOT, os.W_OK):
            return
    except OSError:
        return
    os.environ["PYTEST_DEBUG_TEMPROOT"] = str(MEMORY_ROOT)


def pytest_collection_modifyitems(config, items):
    import os

    if os.environ.get("HSIO_SLOW") == "1":
        return
    skip = pytest.mark.skip(reason="slow: set HSIO_SLOW=1 to run it")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
