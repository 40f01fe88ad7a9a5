"""Shared fixtures: paths to the data beside the repository (skipped where absent)."""

from pathlib import Path

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture
def shared_data() -> Path:
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared data folder {SHARED_DATA} is absent (CI and developer machines have it)")
    return SHARED_DATA


# Long tests (the 100,000-step soak) are marked slow and run only with HSIO_SLOW=1, so that a
# plain `pytest -q` stays bounded.
def pytest_configure(config):
    config.addinivalue_line("markers", "slow: a long test; runs only when the environment sets HSIO_SLOW=1")


def pytest_collection_modifyitems(config, items):
    import os

    if os.environ.get("HSIO_SLOW") == "1":
        return
    skip = pytest.mark.skip(reason="slow: set HSIO_SLOW=1 to run it")
    for item in items:
        if "slow" in item.keywords:
            item.add_marker(skip)
