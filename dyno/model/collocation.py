"""scipy's ``solve_bvp`` with this model's linear algebra, invisible to every other caller.

``solve_bvp`` has no options for its collocation Jacobian or its sparse LU,
and it looks both up as globals of ``scipy.integrate._bvp``.  Instead of
swapping those globals during our calls (which any other thread's
``solve_bvp`` would see), :func:`_private_bvp_module` loads a second,
private copy of that module from scipy's own file and sets the two names in
the copy only: scipy's module, and everybody else's ``solve_bvp``, are
untouched.  Same Newton iterates to rounding (tested against scipy's).

* ``construct_global_jac`` -> :func:`block_global_jac` (the rhs Jacobian is
  block-diagonal by region: 1/15 of the flops, only structural non-zeros), and
  ``compute_jac_indices`` (scipy's dense index lists, which ours does not use) skipped;
* ``splu``: natural order, threshold pivoting 0.1, explicit zeros dropped
  (the collocation Jacobian is block-bidiagonal with diagonal blocks near -I:
  less fill-in than after COLAMD, 3-5x faster at 1550 nodes).

If scipy ever renames those module globals, the copy's ``solve_bvp`` is
scipy's unchanged (correct, ~2x slower).
"""

from __future__ import annotations

import threading

import numpy as np

from dyno.model.equations import BLOCKS, N_STATES

_LOAD_LOCK = threading.Lock()
_PRIVATE = {}


def block_global_jac(n, m, k, i_jac, j_jac, h, df_dy, df_dy_middle, df_dp, df_dp_middle, dbc_dya, dbc_dyb, dbc_dp):
    """scipy's ``construct_global_jac`` for this model, exploiting the block-diagonal rhs Jacobian.

    Same formulas (Kierzenka & Shampine's Lobatto IIIA collocation blocks)
    as ``scipy.integrate._bvp.construct_global_jac``, but the n x n products
    are formed region by region (6, 8, 6, 6 states: 1/15 of the flops), only
    structurally non-zero entries are stored (~1/3), and they are written
    straight into compressed-column order (no COO sort): column (node i, state
    c) holds the rows of interval i-1 (its d1 block), of interval i (d0), then
    the boundary conditions' rows at the two end nodes; a parameter's column
    is dense.
    """
    from scipy.sparse import csc_matrix

    h3 = h[:, None, None]
    n_bc = n + k
    block_size = np.empty(n, dtype=np.int64)
    for blk in BLOCKS:
        block_size[list(blk)] = len(blk)
    lengths = np.empty(n * m + k, dtype=np.int64)
    lengths[:n * m] = np.tile(2 * block_size, m)
    lengths[:n] = block_size + n_bc  # node 0: its d0 rows and the boundary conditions
    lengths[n * (m - 1):n * m] = block_size + n_bc  # node m-1: its d1 rows and the boundary conditions
    lengths[n * m:] = (m - 1) * n + n_bc
    indptr = np.zeros(n * m + k + 1, dtype=np.int64)
    np.cumsum(lengths, out=indptr[1:])
    data = np.empty(indptr[-1])
    indices = np.empty(indptr[-1], dtype=np.int32)
    intervals = np.arange(m - 1)
    for blk in BLOCKS:
        idx = np.sort(np.asarray(blk))
        b = idx.size
        a = np.transpose(df_dy[idx[:, None], idx[None, :], :], (2, 0, 1))
        a_mid = np.transpose(df_dy_middle[idx[:, None], idx[None, :], :], (2, 0, 1))
        eye = np.identity(b)
        d0 = -eye - h3 / 6 * (a[:-1] + 2 * a_mid) - h3**2 / 12 * np.einsum("...ij,...jk->...ik", a_mid, a[:-1])
        d1 = eye - h3 / 6 * (a[1:] + 2 * a_mid) + h3**2 / 12 * np.einsum("...ij,...jk->...ik", a_mid, a[1:])
        rows = (intervals[:, None, None] * n + idx[None, :, None]).astype(np.int32)  # [interval, row a, col c]
        # d1[i] sits in the columns of node i+1, first; d0[i] in those of node i, after d1[i-1] (none at node 0)
        start = indptr[(intervals[:, None] + 1) * n + idx[None, :]]
        pos = start[:, None, :] + np.arange(b)[None, :, None]
        data[pos], indices[pos] = d1, rows
        start = indptr[intervals[:, None] * n + idx[None, :]] + np.where(intervals > 0, b, 0)[:, None]
        pos = start[:, None, :] + np.arange(b)[None, :, None]
        data[pos], indices[pos] = d0, rows
    bc_rows = ((m - 1) * n + np.arange(n_bc)).astype(np.int32)[:, None]
    for node, dbc in ((0, dbc_dya), (m - 1, dbc_dyb)):
        pos = (indptr[node * n + np.arange(n)] + block_size)[None, :] + np.arange(n_bc)[:, None]
        data[pos], indices[pos] = dbc, bc_rows
    if k > 0:
        fp = np.transpose(df_dp, (2, 0, 1))
        fp_mid = np.transpose(df_dp_middle, (2, 0, 1)).copy()
        a_mid_full = np.transpose(df_dy_middle, (2, 0, 1))
        diff = fp[:-1] - fp[1:]
        for blk in BLOCKS:
            idx = np.asarray(blk)
            fp_mid[:, idx, :] += 0.125 * h3 * np.einsum("...ij,...jk->...ik", a_mid_full[:, idx[:, None], idx[None, :]],
                                                       diff[:, idx, :])
        d_p = -h3 / 6 * (fp[:-1] + fp[1:] + 4 * fp_mid)  # [interval, state, parameter]
        first = indptr[n * m]
        data[first:] = np.concatenate([d_p.reshape((m - 1) * n, k), dbc_dp], axis=0).T.ravel()
        indices[first:] = np.tile(np.arange((m - 1) * n + n_bc, dtype=np.int32), k)
    size = n * m + k
    return csc_matrix((data, indices, indptr), shape=(size, size))


def _private_bvp_module():
    """A private copy of ``scipy.integrate._bvp`` with our two functions (loaded once, thread-safe)."""
    with _LOAD_LOCK:
        mod = _PRIVATE.get("module")
        if mod is not None:
            return mod
        import importlib.util

        import scipy.integrate._bvp as scipy_bvp

        spec = importlib.util.spec_from_file_location("dyno.model._scipy_bvp_private", scipy_bvp.__file__)
        mod = importlib.util.module_from_spec(spec)
        spec.loader.exec_module(mod)
        original_splu = getattr(mod, "splu", None)
        original_jac = getattr(mod, "construct_global_jac", None)
        original_indices = getattr(mod, "compute_jac_indices", None)
        if original_splu is not None and original_jac is not None and original_indices is not None:

            def splu_natural(a, *args, **kwargs):
                a.eliminate_zeros()
                kwargs.setdefault("permc_spec", "NATURAL")
                kwargs.setdefault("diag_pivot_thresh", 0.1)
                return original_splu(a, *args, **kwargs)

            def global_jac(n, *args):
                return block_global_jac(n, *args) if n == N_STATES else original_jac(n, *args)

            def jac_indices(n, m, k):
                # scipy's dense (row, col) lists for its own assembly (~4 ms at 400 nodes, every Newton
                # solve): ours builds its own from the blocks
                return (None, None) if n == N_STATES else original_indices(n, m, k)

            mod.splu, mod.construct_global_jac, mod.compute_jac_indices = splu_natural, global_jac, jac_indices
        _PRIVATE["module"] = mod
        return mod


def solve_bvp_fast(fun, bc, x, y, p=None, **kwargs):
    """``scipy.integrate.solve_bvp`` (same arguments and result) with this model's linear algebra."""
    return _private_bvp_module().solve_bvp(fun, bc, x, y, p, **kwargs)
