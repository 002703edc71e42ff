"""The two setups as one model: the camera transform ``C``, the marker-side transform ``K`` and the
per-sample robot transform ``M_i`` (`handeye.calib.model`), and the marker rotation that fits given ``C``."""

from __future__ import annotations

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.setup import Setup


def split(X, Y, A, setup: str):
    """Camera transform ``C``, marker-side transform ``K`` and per-sample ``M_i`` (module docstring)."""
    if setup == Setup.EYE_TO_HAND:
        return Y, X, A
    return X, Y, tf.invert(A)


def join(C, K, setup: str):
    """``(X, Y)`` from the camera transform ``C`` and the marker-side transform ``K``."""
    return (K, C) if setup == Setup.EYE_TO_HAND else (C, K)


def marker_rotation(C, M, R_B) -> np.ndarray:
    """Best ``R_K`` given ``C`` for pose data: chordal mean of ``R_M^T R_C R_B``."""
    S = (np.swapaxes(M[:, :3, :3], 1, 2) @ C[:3, :3] @ R_B).sum(axis=0)
    return tf.project_to_so3(S)
