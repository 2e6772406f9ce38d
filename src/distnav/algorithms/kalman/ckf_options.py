"""The options of the consensus Kalman filter's front doors (paper 003 §4), in the house style of
:mod:`distnav._settings`: one frozen object, validated once when it is built, with documented defaults.

:class:`CKFOptions` is what :func:`~distnav.algorithms.kalman.ckf.iterate_ckf` takes (``options=`` and/or keyword
changes to it); :class:`CKFRunOptions` adds what :func:`~distnav.algorithms.kalman.ckf.ckf` keeps of the series.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from distnav._checks import check_field_types
from distnav.algorithms.kalman.ckf_design import consensus_rounds
from distnav.errors import ModelError
from distnav.network.weights import ConsensusWeights

__all__ = ["CKFOptions", "CKFRunOptions", "ConsensusProtocol", "LocalPrecision", "Transport"]

Transport = Literal["matrices", "relay"]
"""How the CKF's consensus travels: the mixed matrices every round, or the raw records (:mod:`.relay`)."""
LocalPrecision = Literal["exact", "bound"]
"""Node-local form of the Fig. 7 variance (:mod:`distnav.algorithms.kalman.ckf_qc`)."""
ConsensusProtocol = str | int | ConsensusWeights | Sequence[ConsensusWeights]
"""A consensus protocol: a Table 1 name or number (``"P1"``…``"P4"``), one weight object, or one per session."""


@dataclass(frozen=True, eq=False, kw_only=True)
class CKFOptions:
    """Options of :func:`~distnav.algorithms.kalman.ckf.iterate_ckf` (default in brackets), validated once.

    Fields
    ------
    protocol : [``"P3"``] a Table 1 name or number, one :class:`~distnav.network.weights.ConsensusWeights` or one
        per session.
    rounds : [None] ``k_n``, the consensus rounds per epoch; or instead both time scales
    sampling_interval_s : [None] Δ (s) and
    sending_interval_s : [None] δ (s), ``k_n = ⌊Δ/δ⌋`` (Fig. 5). One of the two forms must be given by the time
        the filter starts (an object without either is a partial one, completed by keyword changes).
    variance : [True] the error-variance recursion of Fig. 7 alongside.
    monitor : [True] the consensus deviation from the exact averages (a global reduction: monitoring only).
    local_precision : [None] ``"exact"`` or ``"bound"``: node-local Fig. 7 (:mod:`distnav.algorithms.kalman.ckf_qc`).
    test_level : [None] innovation tests at that level (needs ``local_precision`` and raw observations).
    transport : [``"matrices"``] or ``"relay"`` (:mod:`distnav.algorithms.kalman.relay`).
    """

    protocol: ConsensusProtocol = "P3"
    rounds: int | None = None
    sampling_interval_s: float | None = None
    sending_interval_s: float | None = None
    variance: bool = True
    monitor: bool = True
    local_precision: LocalPrecision | None = None
    test_level: float | None = None
    transport: Transport = "matrices"

    def __post_init__(self) -> None:
        check_field_types(self, error=ModelError)  # types first, naming the field (issue 29)
        if self.rounds is not None or self.sampling_interval_s is not None or self.sending_interval_s is not None:
            _ = self.k_n  # either form, checked; neither is refused when the filter starts (a partial object is fine)
        if self.local_precision not in (None, "exact", "bound"):
            raise ModelError(f"local_precision must be 'exact', 'bound' or None, got {self.local_precision!r}")
        if self.transport not in ("matrices", "relay"):
            raise ModelError(f"transport must be 'matrices' or 'relay', got {self.transport!r}")

    @property
    def k_n(self) -> int:
        """The consensus rounds per epoch: ``rounds``, or ``⌊Δ/δ⌋`` from the two time scales (paper 003 §4.1)."""
        rounds, sampling, sending = self.rounds, self.sampling_interval_s, self.sending_interval_s
        if rounds is not None:
            if sampling is not None or sending is not None:
                raise ModelError("give either rounds or (sampling_interval_s, sending_interval_s), not both")
            if int(rounds) != rounds or rounds < 0:
                raise ModelError(f"rounds must be a non-negative integer, got {rounds}")
            return int(rounds)
        if sampling is None or sending is None:
            raise ModelError("give rounds, or both sampling_interval_s (Δ) and sending_interval_s (δ)")
        return consensus_rounds(sampling, sending)


@dataclass(frozen=True, eq=False, kw_only=True)
class CKFRunOptions(CKFOptions):
    """:class:`CKFOptions` plus (default in brackets)

    Fields
    ------
    store_matrices : [False] keep ``P_i,t|t`` and ``I_i,t|t`` of every epoch in
        :func:`~distnav.algorithms.kalman.ckf.ckf`'s series.
    """

    store_matrices: bool = False
