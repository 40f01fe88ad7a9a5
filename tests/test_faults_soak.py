"""The soak of bench/bench_soak.py: a run over Modbus TCP with faults injected on a seeded
schedule loses no step. Bounded in CI (2,000 steps); the 100,000-step version runs with
HSIO_SLOW=1 (marked slow)."""

from __future__ import annotations

import pytest


def check(r: dict, steps: int) -> None:
    assert r["stopped"] == ""
    assert r["steps"] == r["recorded"] == steps
    assert r["lost_or_repeated"] == 0 and r["consecutive"] and r["finite"]
    assert r["faults_total"] >= 1 and r["retries"] >= 1


def test_soak_bounded(tmp_path, load_bench):
    r = load_bench("bench_soak").soak(2000, every=400, seed=11, workdir=tmp_path)
    check(r, 2000)
    assert {"drop", "corrupt"} <= set(r["faults"])


@pytest.mark.slow
def test_soak_100000_steps(tmp_path, load_bench):
    r = load_bench("bench_soak").soak(100_000, every=2000, seed=7, workdir=tmp_path)
    check(r, 100_000)
    assert r["faults_total"] >= 100
