"""distnav.options: building an options object from the command line's same-named options."""

from __future__ import annotations

import argparse
from dataclasses import dataclass

from distnav.options import fields_from_args


@dataclass(frozen=True)
class _Opts:
    sigma_m: float = 1.0
    loss: str = "linear"
    level: float = 0.001


def test_fields_from_args_takes_the_same_named_options_only():
    """Only the dataclass's fields are taken (not the other options of the command), only those the command line
    has (a missing one keeps its default), and none of those named in ``but``."""
    args = argparse.Namespace(sigma_m=0.1, loss="cauchy", out="folder", strict=True)
    assert fields_from_args(args, _Opts) == {"sigma_m": 0.1, "loss": "cauchy"}
    assert fields_from_args(args, _Opts, but=("loss",)) == {"sigma_m": 0.1}
    assert _Opts(**fields_from_args(args, _Opts, but=("loss",)), loss="huber") == _Opts(sigma_m=0.1, loss="huber")
