"""GNSS models: constants, geometry, orbits (broadcast, SP3, synthetic), observables and weighting, RINEX and
bias-product readers, and the satellite code-bias model of paper 000 §5 (:mod:`.codebias`).

Modules are imported explicitly (``from distnav.models.gnss.geometry import pierce_point``); nothing heavy is
imported here, so ``import distnav.models.gnss`` stays cheap.
"""
