"""Partition files: the rank of every node, one per line as text or a ``.npy`` array.

The reader, :func:`distnav.network.partition.read_partition`, is in the network layer (the exchange reads the file on
every rank at start-up); the writer is here, with the other file writers.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from distnav.network.partition import read_partition

__all__ = ["write_partition", "read_partition"]


def write_partition(path: str | os.PathLike[str], owner: np.ndarray) -> Path:
    """Write an owner array (rank of every node): ``.npy`` binary, anything else as text, one rank per line."""
    out = Path(path)
    arr = np.asarray(owner, dtype=np.int64)
    if out.suffix == ".npy":
        np.save(out, arr)
    else:
        out.write_text(
            f"# distnav partition: rank of each of {arr.size} nodes, one per line\n"
            + "\n".join(map(str, arr.tolist()))
            + "\n"
        )
    return out
