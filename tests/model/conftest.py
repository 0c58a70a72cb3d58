"""Shared full-model solutions: solved once per session, reused by every test."""

import pytest

from dyno.model.params import TABLE_6_1, TABLE_6_1_POINT


@pytest.fixture(scope="session")
def table_6_1():
    from dyno.model.solution import solve_point

    return solve_point(TABLE_6_1, TABLE_6_1_POINT)


@pytest.fixture(scope="session")
def table_6_1_rounded(table_6_1):
    """Same case with the rounded friction corner (cheap warm starts for parameter homotopies)."""
    from dyno.model.solution import solve_point

    return solve_point(TABLE_6_1, TABLE_6_1_POINT, guess=table_6_1, friction_corner=0.2)
