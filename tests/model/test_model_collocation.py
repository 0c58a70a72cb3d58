"""Our collocation linear algebra lives in a private copy of scipy's _bvp module: nobody else sees it."""

import threading

import numpy as np

from dyno.model import collocation
from dyno.model.solution import solve_point


def test_scipy_module_untouched_while_we_solve():
    import scipy.integrate._bvp as scipy_bvp
    from scipy.integrate import solve_bvp

    original = (scipy_bvp.splu, scipy_bvp.construct_global_jac)
    done, seen, results = threading.Event(), [], []

    def ours():
        try:
            results.append(solve_point(slip_threshold_m_s=1e-2))
        finally:
            done.set()

    worker = threading.Thread(target=ours)
    worker.start()
    # Another caller's solve_bvp during our solve: y'' = -y, y(0) = 0, y(pi/2) = 1 -> sin.
    x = np.linspace(0, np.pi / 2, 11)
    while not done.is_set():
        seen.append((scipy_bvp.splu, scipy_bvp.construct_global_jac) == original)
        res = solve_bvp(lambda t, y: np.vstack([y[1], -y[0]]), lambda a, b: np.array([a[0], b[0] - 1.0]), x,
                        np.zeros((2, x.size)))
        assert res.status == 0 and np.allclose(res.sol(x)[0], np.sin(x), atol=1e-3)
    worker.join()
    assert results and results[0].summary["converged"]
    assert seen and all(seen)  # never swapped, not even for a moment
    private = collocation._private_bvp_module()
    assert private is not scipy_bvp and private.splu is not scipy_bvp.splu
    assert private.construct_global_jac is not scipy_bvp.construct_global_jac
