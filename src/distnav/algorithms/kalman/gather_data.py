"""What a fusion centre needs of each node of a filter, in bytes (the yardstick of issue 27).

Every epoch, node ``i`` could send a central filter its normal equations of that epoch (paper 003 eq. (24)),
packed over the ``q_{i,t}`` states its observations touch (:func:`~distnav.algorithms.lsq.gather_data.
packed_normal_bytes`): the cheapest form a series that holds normals only can be gathered in. Series of raw
observations (GNSS) are better measured by their observation count (``OBSERVATION_RECORD_BYTES`` each).
"""

from __future__ import annotations

import numpy as np

from distnav.algorithms.kalman.measurements import MeasurementSeries
from distnav.algorithms.lsq.gather_data import packed_normal_bytes

__all__ = ["NORMALS_DATA", "normal_bytes_per_node"]

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
