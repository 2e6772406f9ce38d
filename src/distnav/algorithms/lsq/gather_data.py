"""What a fusion centre needs of each node of a linear problem, in bytes (the yardstick of issue 27).

For :func:`distnav.algorithms.result.compare_with_gather`: node ``i`` of ``y_i = A_i x + e_i, C(e_i) = R_i``
(paper 000 eq. (1)) can hand a fusion centre either

* its **observations**: ``y_i`` and the variances (``m_i`` float64 each; a full ``R_i`` as its packed upper
  triangle), and the non-zero entries of ``A_i`` with their column indices (float64 + int32); or
* its **normal equations** reduced to the ``q_i`` unknowns its observations touch: ``N_i = A_iᵀ R_i⁻¹ A_i``
  packed (``q_i(q_i+1)/2`` float64), ``b_i = A_iᵀ R_i⁻¹ y_i`` (``q_i`` float64) and the ``q_i`` column indices
  (int32) — enough for the BLUE, not for residual tests.

Each node sends whichever is smaller: the cheapest honest fusion centre, so the distributed run is compared with
the hardest yardstick.
"""

from __future__ import annotations

import numpy as np

from distnav.algorithms.lsq.blue import LinearProblem
from distnav.typing import ArrayLike

__all__ = [
    "FLOAT_BYTES",
    "INDEX_BYTES",
    "GATHER_DATA",
    "OBSERVATION_RECORD_BYTES",
    "node_data_bytes",
    "packed_normal_bytes",
]

FLOAT_BYTES = 8
INDEX_BYTES = 4
#: One scalar observation as a fusion centre needs it when the design follows from known geometry (a GNSS
#: observation of one satellite at one station and epoch): the value and its variance (float64) and the index of
#: what it observes (int32).
OBSERVATION_RECORD_BYTES = 2 * FLOAT_BYTES + INDEX_BYTES
#: What :func:`node_data_bytes` counts, in words (for reports).
GATHER_DATA = "observations or packed normals, the smaller"


def node_data_bytes(problem: LinearProblem, *, normals: bool = True) -> np.ndarray:
    """Bytes each node would send a fusion centre (module docstring): ``min(observations, normals)``, or the
    observations alone with ``normals=False`` (a centre that tests the observations needs them)."""
    n = problem.A.shape[0]
    out = np.zeros(n, np.int64)
    for i in range(n):
        m = int(problem.rows[i])
        a = problem.A[i, :m]
        r = problem.R[i, :m, :m]
        diagonal = bool(np.count_nonzero(r - np.diag(np.diag(r))) == 0)
        r_bytes = m * FLOAT_BYTES if diagonal else m * (m + 1) // 2 * FLOAT_BYTES
        observations = m * FLOAT_BYTES + r_bytes + int(np.count_nonzero(a)) * (FLOAT_BYTES + INDEX_BYTES)
        packed = int(packed_normal_bytes(np.count_nonzero(np.any(a != 0, axis=0))))
        out[i] = min(observations, packed) if normals else observations
    return out


def packed_normal_bytes(observed_states: ArrayLike) -> np.ndarray:
    """Bytes of normal equations over ``q`` observed states: ``N`` packed (``q(q+1)/2`` float64), ``b`` (``q``
    float64) and the ``q`` state indices (int32), elementwise over ``observed_states`` (= ``q``)."""
    q = np.asarray(observed_states, np.int64)
    return (q * (q + 1) // 2 + q) * FLOAT_BYTES + q * INDEX_BYTES
