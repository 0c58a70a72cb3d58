import json
from dataclasses import replace
from pathlib import Path

import pytest

from dyno.app import RunOptions, run_test
from dyno.control.controller import TestPlan

# A shorter plan for tests that only need a few points (aborts, kills).
QUICK_PLAN = replace(TestPlan(), max_measure_s=3.0, warmup_s=2.0)


@pytest.fixture(scope="session")
def full_run(tmp_path_factory):
    """One complete default simulated test, shared by the tests that inspect it."""
    out = tmp_path_factory.mktemp("runs") / "full"
    return run_test(RunOptions(sim=True, seed=1, out_dir=out))


@pytest.fixture(scope="session")
def faulty_run(tmp_path_factory):
    out = tmp_path_factory.mktemp("runs") / "faulty"
    return run_test(RunOptions(sim=True, seed=1, fault_rate=0.05, out_dir=out))
