"""Linear least squares over a network (paper 000 §2–4): the BLUE, the method of multipliers and ADMM.

Rooms, from the bottom up: :mod:`~distnav.algorithms.lsq.conditions` (the weight ``W`` and the rank check),
:mod:`~distnav.algorithms.lsq.blue` (the problem, the centralized BLUE, the method of multipliers and
single-consensus ADMM), :mod:`~distnav.algorithms.lsq.xupdate` (the x-update
methods), :mod:`~distnav.algorithms.lsq.kernel` (the ADMM iteration over a block of nodes),
:mod:`~distnav.algorithms.lsq.driver` (options, stopping, results), :mod:`~distnav.algorithms.lsq.admm` (the front
door), :mod:`~distnav.algorithms.lsq.nonlinear` (linearized and nonlinear ADMM) and :mod:`~distnav.algorithms.lsq.qc`
(distributed precision and data snooping). The problem and the BLUE are re-exported here.
"""

from distnav.algorithms.lsq.blue import *  # noqa: F403  (the front doors, re-exported)
from distnav.algorithms.lsq.blue import __all__ as __all__
