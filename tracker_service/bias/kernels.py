"""The separated bias filter's gate in one compiled pass per update (numba, ``cache=True``).

``gate_statistics`` is each observation's normalised innovation squared nu^T S^-1 nu with
S = N + C P C^T, the numpy reference's (``separated.gate_statistics_reference``: a batched
matmul, ``np.linalg.solve`` and ``einsum``, a dozen calls and the gufuncs' set-up per
update) in one loop with the 2x2 inverse written out. Its value only decides whether
an observation is taken (``<= outlier_gate``): the estimates are computed from numpy's
arithmetic either way, so the two agree to the bit unless a statistic lies within a few
ulps of the gate (tests/test_bias_kernels.py holds them to 1e-9 relative).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from tracker_service.numba_symbols import numba

__all__ = ["gate_statistics"]

FloatArray = npt.NDArray[np.float64]


@numba.njit(cache=True, error_model="numpy")
def gate_statistics(
    C: FloatArray, P: FloatArray, noise: FloatArray, nu: FloatArray
) -> FloatArray:  # pragma: no cover (compiled)
    """nu_n^T (noise_n + C_n P C_n^T)^-1 nu_n per row: C (n, 2, k), P (>= k, >= k) (its
    leading k x k block: the states C reaches), noise (n, 2, 2), nu (n, 2)."""
    n, _, k = C.shape
    out = np.empty(n)
    cp = np.empty((2, k))
    s = np.empty((2, 2))
    for row in range(n):
        for i in range(2):
            for j in range(k):
                total = 0.0
                for m in range(k):
                    total += C[row, i, m] * P[m, j]
                cp[i, j] = total
        for i in range(2):
            for j in range(2):
                total = noise[row, i, j]
                for m in range(k):
                    total += cp[i, m] * C[row, j, m]
                s[i, j] = total
        a, b, c, d = s[0, 0], s[0, 1], s[1, 0], s[1, 1]
        x, y = nu[row, 0], nu[row, 1]
        out[row] = (d * x * x - (b + c) * x * y + a * y * y) / (a * d - b * c)
    return out
