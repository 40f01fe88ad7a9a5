"""The soak of bench/bench_soak.py: a run over Modbus TCP with faults injected on a seeded
schedule loses no step. Bounded in CI (2,000 steps); the 100,000-step version runs with
HSIO_SLOW=1 (marked slow)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest

BENCH = Path(__file__).resolve().parents[1] / "bench" / "bench_soak.py"


def load_bench():
    spec = importlib.util.spec_from_file_location("bench_soak", BENCH)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def check(r: dict, steps: int) -> None:
    assert r["stopped"] == ""
    assert r["steps"] == r["recorded"] == steps
    assert r["lost_or_repeated"] == 0 and r["consecutive"] and r["finite"]
    assert r["faults_total"] >= 1 and r["retries"] >= 1


def test_soak_bounded(tmp_path):
    r = load_bench().soak(2000, every=400, seed=11, workdir=tmp_path)
    check(r, 2000)
    assert {"drop", "corrupt"} <= set(r["faults"])


@pytest.mark.slow
def test_soak_100000_steps(tmp_path):
    r = load_bench().soak(100_000, every=2000, seed=7, workdir=tmp_path)
    check(r, 100_000)
    assert r["faults_total"] >= 100
