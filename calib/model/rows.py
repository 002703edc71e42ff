"""Batched 3x3 algebra on the entries as contiguous rows (9, N): closed forms that beat a batched LAPACK
call per matrix, and strided (N, 3, 3) columns."""

from __future__ import annotations

import numpy as np


#: Row and column of each entry of a 3x3 matrix in row-major order: ``(a b^T).flat == a[ROW] * b[COL]``.
ROW, COL = np.divmod(np.arange(9), 3)


EYE_ROW = np.eye(3).reshape(9)


def rows(a) -> np.ndarray:
    """Entries of 3x3 matrices (N, 3, 3) as contiguous rows (9, N), row-major order (strided columns are slower)."""
    return np.ascontiguousarray(np.reshape(a, (-1, 9)).T)


def inv3(a) -> np.ndarray:
    """Inverses (N, 3, 3) of 3x3 matrices by the adjugate (cheaper than a batched LAPACK call per matrix)."""
    a00, a01, a02, a10, a11, a12, a20, a21, a22 = rows(a)
    c = np.empty((9, len(a00)))
    c[0] = a11 * a22 - a12 * a21
    c[1] = a02 * a21 - a01 * a22
    c[2] = a01 * a12 - a02 * a11
    c[3] = a12 * a20 - a10 * a22
    c[4] = a00 * a22 - a02 * a20
    c[5] = a02 * a10 - a00 * a12
    c[6] = a10 * a21 - a11 * a20
    c[7] = a01 * a20 - a00 * a21
    c[8] = a00 * a11 - a01 * a10
    c /= a00 * c[0] + a01 * c[3] + a02 * c[6]
    return np.ascontiguousarray(c.T).reshape(-1, 3, 3)


def sym3_positive(a, margin: float) -> np.ndarray:
    """Whether each symmetric 3x3 matrix (N, 3, 3) minus ``margin I`` is positive definite (N,), i.e. its smallest
    eigenvalue exceeds ``margin`` (Sylvester's criterion: the leading minors; the upper triangle is read)."""
    a00, a01, a02, _, a11, a12, _, _, a22 = rows(a)
    return sym3_positive_rows(a00, a01, a02, a11, a12, a22, margin)


def sym3_positive_rows(a00, a01, a02, a11, a12, a22, margin: float) -> np.ndarray:
    """`sym3_positive` of the upper-triangle entries, each (N,)."""
    b00, b11, b22 = a00 - margin, a11 - margin, a22 - margin
    m2 = b00 * b11 - a01 * a01
    det = b00 * (b11 * b22 - a12 * a12) - a01 * (a01 * b22 - a12 * a02) + a02 * (a01 * a12 - b11 * a02)
    return (b00 > 0) & (m2 > 0) & (det > 0)
