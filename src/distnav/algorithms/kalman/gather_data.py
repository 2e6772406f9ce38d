"""What a fusion centre needs of each node of a filter, in bytes (the yardstick of issue 27).

Every epoch, node ``i`` could send a central filter its normal equations of that epoch (paper 003 eq. (24)),
packed over the ``q_{i,t}`` states its observations touch (:func:`~distnav.algorithms.lsq.gather_data.
packed_normal_bytes`): the cheapest form a series that holds normals only can be gathered in. Series of raw
observations (GNSS) are better measured by their observation count (``OBSERVATION_RECORD_BYTES`` each).
"""

from __future__ import annotations

import numpy as np

from distnav.algorithms.kalman.measurements import MeasurementSeries
from distnav.algorithms.lsq.gather_data import (
    FLOAT_BYTES,
    INDEX_BYTES,
    OBSERVATION_RECORD_BYTES,
    packed_normal_bytes,
)

__all__ = [
    "NORMALS_DATA",
    "OBSERVATIONS_DATA",
    "RECORDS_DATA",
    "normal_bytes_per_node",
    "observation_bytes_per_node",
    "record_bytes_per_node",
]

#: What :func:`record_bytes_per_node` counts, in words (for reports).
RECORDS_DATA = f"every epoch's observations ({OBSERVATION_RECORD_BYTES} B each: value, σ, satellite)"

#: What :func:`observation_bytes_per_node` counts, in words (for reports).
OBSERVATIONS_DATA = "every epoch's observations of each node (value, σ, non-zero design entries)"

#: What :func:`normal_bytes_per_node` counts, in words (for reports).
NORMALS_DATA = "every epoch's normal equations of each node (packed, over the states it observes)"


def normal_bytes_per_node(series: MeasurementSeries) -> np.ndarray:
    """Bytes per node, summed over the epochs, of its packed per-epoch normal equations (module docstring)."""
    total = np.zeros(series.n_nodes, np.int64)
    for t in range(series.n_epochs):
        N, _ = series.normals(t)
        q = np.count_nonzero(np.diagonal(N, axis1=1, axis2=2) > 0, axis=1)
        total += np.where(q > 0, packed_normal_bytes(q), 0)
    return total


def observation_bytes_per_node(series: MeasurementSeries) -> np.ndarray:
    """Bytes per node, summed over the epochs, of its raw observations (a centre that tests them needs them):
    per row the value and σ (float64) and each non-zero design entry with its state index (float64 + int32)."""
    total = np.zeros(series.n_nodes, np.int64)
    for t in range(series.n_epochs):
        A, _, node = series.observations(t)
        per_row = 2 * FLOAT_BYTES + np.count_nonzero(A, axis=1) * (FLOAT_BYTES + INDEX_BYTES)
        total += np.bincount(node, weights=per_row, minlength=series.n_nodes).astype(np.int64)
    return total


def record_bytes_per_node(tracked: np.ndarray) -> np.ndarray:
    """Bytes per node of its observations as :data:`OBSERVATION_RECORD_BYTES` records, from a mask ``tracked``
    (epoch, node, satellite) of what each node observed (GNSS series: the design follows from the orbits)."""
    counts: np.ndarray = np.asarray(tracked).sum(axis=(0, 2)).astype(np.int64)
    return counts * OBSERVATION_RECORD_BYTES
