"""The boundary conditions' exact Jacobian (complex step, dyno.model.boundary.make_bc_jac) against central
differences, at states that matter: a converged solution, and geometric guesses at the stiff corners of the
model (low wrap, heavy clamp, near gross slip), both variants, each also perturbed off its special point (at a
solution the interface point loads vanish; their derivatives do not)."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from dyno.model.boundary import make_bc, make_bc_jac
from dyno.model.equations import make_case
from dyno.model.guess import initial_guess
from dyno.model.params import TABLE_6_1, TABLE_6_1_POINT

pytestmark = pytest.mark.quick


def _central_difference(bc, ya, yb, p):
    z0 = np.concatenate([ya, yb, p])
    n = ya.size
    cols = []
    for j in range(z0.size):
        h = 1e-6 * (1.0 + abs(z0[j]))
        zp, zm = z0.copy(), z0.copy()
        zp[j] += h
        zm[j] -= h
        f = [bc(z[:n], z[n:2 * n], z[2 * n:]) for z in (zp, zm)]
        cols.append((f[0] - f[1]) / (2 * h))
    jac = np.array(cols).T
    return jac[:, :n], jac[:, n:2 * n], jac[:, 2 * n:]


def _check(case, ya, yb, p):
    bc = make_bc(case)
    exact = make_bc_jac(case, bc)(ya, yb, p)
    fd = _central_difference(bc, ya, yb, p)
    assert [a.shape for a in exact] == [(34, 26), (34, 26), (34, 8)]
    for name, a, b in zip(("dbc/dya", "dbc/dyb", "dbc/dp"), exact, fd):
        scale = 1.0 + np.abs(a)
        err = np.abs(a - b) / scale
        i, j = np.unravel_index(np.argmax(err), err.shape)
        # central differences carry ~1e-9 of truncation and rounding here; a wrong derivative is O(1) off
        assert err.max() < 1e-5, f"{case.name()} {name}[{i},{j}]: exact {a[i, j]:.9g}, differences {b[i, j]:.9g}"
    return exact


CASES = {
    "table 6.1": (TABLE_6_1_POINT, "corrected"),
    "as published": (TABLE_6_1_POINT, "as_published"),
    "low wrap (ratio 3.5)": (replace(TABLE_6_1_POINT, ratio=3.5), "corrected"),
    "heavy clamp (2,500 N at ratio 0.6)": (replace(TABLE_6_1_POINT, ratio=0.6, slack_tension_n=None,
                                                   primary_axial_force_n=2500.0), "corrected"),
    "near gross slip (40 N*m, slack 60 N)": (replace(TABLE_6_1_POINT, primary_torque_nm=40.0, slack_tension_n=60.0),
                                             "corrected"),
}


@pytest.mark.parametrize("label", list(CASES))
def test_bc_jacobian_equals_differences_at_geometric_guesses(label):
    op, variant = CASES[label]
    case = make_case(TABLE_6_1, op, variant=variant)
    _, y, p = initial_guess(case, 41)
    rng = np.random.default_rng(7)
    for scale in (0.0, 0.05):  # the guess itself, then a state off it
        ya = y[:, 0] * (1 + scale * rng.standard_normal(y.shape[0]))
        yb = y[:, -1] * (1 + scale * rng.standard_normal(y.shape[0]))
        _check(case, ya, yb, p * (1 + scale * rng.standard_normal(p.size)))


def test_bc_jacobian_at_a_converged_solution_and_its_point_load_terms(table_6_1):
    raw = table_6_1.raw
    exact = _check(raw.case, raw.y[:, 0], raw.y[:, -1], raw.p)
    # the torque condition's row carries the interface point loads' torque (balance.point_load_torque_nm):
    # it depends on the span shears (not only on P_M), so those columns are non-zero
    d_ya, d_yb, _ = exact
    torque_row = 3
    assert np.count_nonzero(np.abs(d_ya[torque_row]) > 1e-12) + np.count_nonzero(np.abs(d_yb[torque_row]) > 1e-12) > 3


def test_bc_is_the_same_function_on_a_batch():
    case = make_case(TABLE_6_1, TABLE_6_1_POINT)
    _, y, p = initial_guess(case, 41)
    bc = make_bc(case)
    batch = bc(np.stack([y[:, 0]] * 3, axis=1), np.stack([y[:, -1]] * 3, axis=1), np.stack([p] * 3, axis=1))
    assert batch.shape == (34, 3)
    assert np.allclose(batch, bc(y[:, 0], y[:, -1], p)[:, None], rtol=0, atol=1e-13)
