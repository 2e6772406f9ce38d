"""Paper reproductions. Each entry maps a CLI name to its module (see :mod:`distnav.experiments.common`).

Listed in the order ``distnav demo`` runs them. A module that does not exist yet is skipped by the demo and
refused by ``distnav reproduce`` with a clear message.
"""

from __future__ import annotations

import importlib
import importlib.util
from types import ModuleType

from distnav.errors import UsageError

EXPERIMENTS: dict[str, str] = {
    "consensus": "distnav.experiments.consensus",
    "admm": "distnav.experiments.admm",
    "ckf": "distnav.experiments.ckf",
    "uwb": "distnav.experiments.uwb",
    "uwb-field": "distnav.experiments.uwb_field",
    "codebias": "distnav.experiments.codebias",
    "ckf-ionosphere": "distnav.experiments.ckf_ionosphere",
    "qc": "distnav.experiments.qc",
}


def available() -> list[str]:
    """Names of the experiments whose modules are present."""
    return [name for name, mod in EXPERIMENTS.items() if importlib.util.find_spec(mod) is not None]


def load(name: str) -> ModuleType:
    """The module of experiment ``name``; :class:`~distnav.errors.UsageError` (a ``ValueError``) if unknown."""
    if name not in EXPERIMENTS:
        raise UsageError(f"unknown experiment {name!r}; choose one of {', '.join(EXPERIMENTS)}")
    if importlib.util.find_spec(EXPERIMENTS[name]) is None:
        raise UsageError(f"experiment {name!r} is not implemented in this version of distnav")
    return importlib.import_module(EXPERIMENTS[name])
