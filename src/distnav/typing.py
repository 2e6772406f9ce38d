"""Array aliases used in distnav's signatures.

``FloatArray`` is a float64 numpy array of any shape, ``IntArray`` an integer one, ``BoolArray`` a mask;
``ArrayLike`` is anything :func:`numpy.asarray` accepts (what public front doors take before validating).
"""

from __future__ import annotations

from typing import Any, TypeAlias

import numpy as np
import numpy.typing as npt

__all__ = ["ArrayLike", "BoolArray", "FloatArray", "IntArray"]

FloatArray: TypeAlias = npt.NDArray[np.float64]
IntArray: TypeAlias = npt.NDArray[np.intp] | npt.NDArray[np.int64]
BoolArray: TypeAlias = npt.NDArray[np.bool_]
AnyArray: TypeAlias = npt.NDArray[Any]
ArrayLike: TypeAlias = npt.ArrayLike
