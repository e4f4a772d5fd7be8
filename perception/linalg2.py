"""Determinant, solve and inverse of one small float64 matrix, bit-identical to ``np.linalg``.

``np.linalg.det``/``solve``/``inv`` spend 5-10 us per call on argument checks and type dispatch
around a sub-microsecond LAPACK call; the matcher calls them a few times per fix on 2x2 matrices.
These helpers call the same LAPACK kernels (numpy's ``_umath_linalg`` gufuncs, float64 signature)
directly, so the results are the same bits. Inputs must be float64 arrays: a (2, 2) matrix (and a
(2,) right-hand side). A singular matrix gives NaN entries and numpy's "invalid value" RuntimeWarning instead of
``LinAlgError``; callers here only pass positive-definite curvatures.
"""

from __future__ import annotations

import numpy as np

try:   # the gufuncs np.linalg itself calls (numpy >= 1.8; private module, hence the fallback)
    from numpy.linalg import _umath_linalg as _ul

    def det2(a: np.ndarray) -> float:
        """``float(np.linalg.det(a))`` for a float64 square matrix."""
        return float(_ul.det(a, signature="d->d"))

    def solve2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``np.linalg.solve(a, b)`` for a float64 square matrix and a 1-D float64 vector."""
        return _ul.solve1(a, b, signature="dd->d")

    def inv2(a: np.ndarray) -> np.ndarray:
        """``np.linalg.inv(a)`` for a float64 square matrix."""
        return _ul.inv(a, signature="d->d")
except ImportError:  # pragma: no cover - numpy moved its internals: the public, slower calls
    def det2(a: np.ndarray) -> float:
        """``float(np.linalg.det(a))``."""
        return float(np.linalg.det(a))

    def solve2(a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """``np.linalg.solve(a, b)``."""
        return np.linalg.solve(a, b)

    def inv2(a: np.ndarray) -> np.ndarray:
        """``np.linalg.inv(a)``."""
        return np.linalg.inv(a)
