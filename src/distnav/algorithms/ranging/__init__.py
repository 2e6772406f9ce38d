"""Distributed nonlinear least squares for UWB ranging networks (paper 002).

Rooms, from the bottom up: :mod:`~distnav.algorithms.ranging.data` (the problem and result types),
:mod:`~distnav.algorithms.ranging.losses` (robust losses), :mod:`~distnav.algorithms.ranging.objective`,
:mod:`~distnav.algorithms.ranging.stop` (stop rules), :mod:`~distnav.algorithms.ranging.damped` and
:mod:`~distnav.algorithms.ranging.lm` (centralized LM), :mod:`~distnav.algorithms.ranging.neighbourhoods`
(index maps, mixing, line searches), :mod:`~distnav.algorithms.ranging.qc`,
:mod:`~distnav.algorithms.ranging.local_lm`, :mod:`~distnav.algorithms.ranging.options` (the front doors' settings),
:mod:`~distnav.algorithms.ranging.plan`,
:mod:`~distnav.algorithms.ranging.neighbourhood_offsets`, :mod:`~distnav.algorithms.ranging.neighbourhood`,
:mod:`~distnav.algorithms.ranging.line_search_pair`, :mod:`~distnav.algorithms.ranging.refine`,
:mod:`~distnav.algorithms.ranging.subnetwork`, :mod:`~distnav.algorithms.ranging.precision`,
:mod:`~distnav.algorithms.ranging.covariance` and the front doors
:mod:`~distnav.algorithms.ranging.csg` (CSG, N-CSG family, N-CLM). Nothing is imported here: import the room.
"""
