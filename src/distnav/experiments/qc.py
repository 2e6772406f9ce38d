"""Reproduction ``qc``: distributed precision and data snooping (issue 12; paper 000 §6's open questions).

Filled in below; :func:`gross_error_problem` is the simulated least-squares network shared by the tests and
``benchmarks/bench_qc.py``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from distnav.algorithms.lsq import LinearProblem
from distnav.network import builders
from distnav.network.graph import Graph


@dataclass(frozen=True, eq=False)
class GrossErrorProblem:
    """A simulated network: ``graph``, the data with gross errors (``problem``) and without (``clean``), the flat
    indices of the corrupted observations (``outliers``, node-major) and the truth ``x``."""

    graph: Graph
    problem: LinearProblem
    clean: LinearProblem
    outliers: np.ndarray
    x: np.ndarray


def gross_error_problem(rng: np.random.Generator, *, n: int = 20, m: int = 3, p: int = 6, n_outliers: int = 2,
                        size_sigma: float = 6.0, mean_degree: float = 5.0) -> GrossErrorProblem:
    """``m < p`` rows per node (every ``N_i`` singular), standard-normal design, σ_j ~ U(0.5, 2) per observation
    (diagonal ``R_i``), and ``n_outliers`` observations shifted by ``± size_sigma·σ_j``."""
    g = builders.connected_random_geometric(n, mean_degree=mean_degree, rng=rng)
    A = rng.normal(size=(n, m, p))
    x = rng.normal(size=p)
    sigma = rng.uniform(0.5, 2.0, size=(n, m))
    y = np.einsum("nmp,p->nm", A, x) + sigma * rng.normal(size=(n, m))
    bad = np.sort(rng.choice(n * m, n_outliers, replace=False))
    y_bad = y.copy().ravel()
    y_bad[bad] += size_sigma * sigma.ravel()[bad] * rng.choice([-1.0, 1.0], n_outliers)
    return GrossErrorProblem(graph=g, problem=LinearProblem.from_stacked(A, y_bad.reshape(n, m), sigma ** 2),
                             clean=LinearProblem.from_stacked(A, y, sigma ** 2), outliers=bad, x=x)
