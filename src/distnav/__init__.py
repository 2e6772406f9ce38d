"""distnav: distributed estimation over sensor networks.

Layers (imports point downwards only): ``network`` → ``exchange`` → ``algorithms`` → ``models`` →
``experiments``/``cli``. See ARCHITECTURE.md.
"""

from __future__ import annotations

__version__ = "0.1.0"

from distnav.errors import (  # noqa: E402
    DataFileError,
    DistnavError,
    ExchangeError,
    GraphError,
    MissingExtraError,
    ModelError,
    WeightsError,
)

__all__ = [
    "__version__",
    "DistnavError",
    "GraphError",
    "WeightsError",
    "ExchangeError",
    "ModelError",
    "DataFileError",
    "MissingExtraError",
]
