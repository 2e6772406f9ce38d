"""Average consensus (paper 003 §3): protocols, schedules, the iteration and the probabilistic measure.

The front doors live in :mod:`distnav.algorithms.consensus.averaging` and are re-exported here, so
``from distnav.algorithms.consensus import average_consensus`` works.
"""

from distnav.algorithms.consensus.averaging import *  # noqa: F403  (the front doors, re-exported)
from distnav.algorithms.consensus.averaging import __all__ as __all__
