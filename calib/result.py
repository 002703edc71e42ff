"""The result of a calibration: the paper's X and Y, named frames, statistics.

Covariance convention (used everywhere in handeye): a 6-vector
``[delta_rotvec (rad), delta_t (m)]`` with ``R_true = Exp(delta_rotvec) @ R_est``
and ``t_true = t_est + delta_t``; ``cov`` is its 6x6 covariance for the
*camera* transform (``T_base_cam`` eye-to-hand, ``T_flange_cam`` eye-in-hand).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from calib.errors import DegenerateMotionError
from calib.model import CameraCorrection
from calib.setup import Setup


def worst_axis_sigma(cov) -> tuple[float, float]:
    """Worst-axis 1-sigma ``(rotation rad, translation m)`` of a 6x6 ``[rotvec, t]`` covariance:
    the square roots of the largest eigenvalues of its rotation and translation blocks."""
    cov = np.asarray(cov, dtype=float)
    s_rot = float(np.sqrt(max(np.linalg.eigvalsh(cov[:3, :3]).max(), 0.0)))
    s_t = float(np.sqrt(max(np.linalg.eigvalsh(cov[3:, 3:]).max(), 0.0)))
    return s_rot, s_t


@dataclass(frozen=True)
class Residuals:
    """Per-sample residuals of ``A_i X = Y B_i`` at the solution.

    Attributes
    ----------
    translation : ndarray, shape (N,)
        Norm of the translation residual per sample, m (for point data: the
        distance between the measured and predicted marker point in the
        camera frame).
    rotation : ndarray, shape (N,), or None
        Rotation residual angle per sample, rad (None for point-only data).
    """

    translation: np.ndarray
    rotation: np.ndarray | None = None

    @property
    def rms_translation(self) -> float:
        return float(np.sqrt(np.mean(self.translation**2)))

    @property
    def max_translation(self) -> float:
        return float(np.max(self.translation))

    @property
    def rms_rotation(self) -> float | None:
        return None if self.rotation is None else float(np.sqrt(np.mean(self.rotation**2)))


@dataclass(frozen=True)
class CalibrationResult:
    """Solution of ``A_i X = Y B_i`` (paper eq. 1) and how much to trust it.

    ``X`` and ``Y`` are the paper's unknowns. Eye-to-hand: ``X = T_flange_marker``,
    ``Y = T_base_cam``. Eye-in-hand: ``X = T_flange_cam``, ``Y = T_base_marker``.
    The point-only method (YKronT') recovers only the translation of the
    marker-side transform and reports identity for its rotation
    (``marker_rotation_known`` is False).
    """

    method: str
    setup: Setup
    X: np.ndarray
    Y: np.ndarray
    n_samples: int
    residuals: Residuals
    cov: np.ndarray | None = None
    marker_rotation_known: bool = True
    inliers: np.ndarray | None = None
    converged: bool = True
    iterations: int = 0
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        # A NaN/inf anywhere means the data did not determine the solution (e.g. a
        # singular information matrix): say so instead of handing NaN downstream.
        parts = {"X": self.X, "Y": self.Y, "cov": self.cov, "residuals.translation": self.residuals.translation,
                 "residuals.rotation": self.residuals.rotation}
        for name, value in parts.items():
            if value is not None and not np.isfinite(np.asarray(value, dtype=float)).all():
                raise DegenerateMotionError(
                    f"{self.method}: the {name} of the solution is not finite; the {self.n_samples} samples "
                    "do not determine every unknown (vary the flange orientation and position more)")

    @property
    def T_base_cam(self) -> np.ndarray:
        self._require(Setup.EYE_TO_HAND, "T_base_cam")
        return self.Y

    @property
    def T_flange_marker(self) -> np.ndarray:
        self._require(Setup.EYE_TO_HAND, "T_flange_marker")
        return self.X

    @property
    def T_flange_cam(self) -> np.ndarray:
        self._require(Setup.EYE_IN_HAND, "T_flange_cam")
        return self.X

    @property
    def T_base_marker(self) -> np.ndarray:
        self._require(Setup.EYE_IN_HAND, "T_base_marker")
        return self.Y

    @property
    def camera_transform(self) -> np.ndarray:
        """``T_base_cam`` (eye-to-hand) or ``T_flange_cam`` (eye-in-hand)."""
        return self.Y if self.setup == Setup.EYE_TO_HAND else self.X

    @property
    def camera_correction(self) -> CameraCorrection:
        """The camera's systematic error the solver estimated (`calib.model.CameraCorrection`; all zero if none).

        ``auto`` estimates it (``info["camera_correction"]``); the paper's methods do not.
        """
        cc = self.info.get("camera_correction") or {}
        return CameraCorrection(**{name: c["value"] for name, c in cc.items() if c["estimated"]})

    @cached_property
    def raw_points_fit(self) -> dict | None:
        """The rigid stand-in for the estimated camera correction, or None without one.

        ``{"transform": G, "misfit_m": rms}``: `calib.model.CameraCorrection.rigid_stand_in`
        of `camera_correction` over the points it was estimated on
        (``info["correction_points"]``, the raw points of the samples in the
        fit). Computed when first asked (the exports ask), not by the solver.
        """
        points = self.info.get("correction_points")
        if points is None:
            return None
        G, misfit = self.camera_correction.rigid_stand_in(points)
        return {"transform": G, "misfit_m": misfit}

    @property
    def camera_transform_raw_points(self) -> np.ndarray:
        """The camera transform for the camera's uncorrected points: what a URDF or a tf should carry.

        ``camera_transform`` pairs with the camera correction ``auto``
        estimated (`camera_correction`: depth scale and offset, focal scale),
        applied to the points first. Where the points reach the consumer
        uncorrected, ``camera_transform @ G`` with ``G`` the rigid stand-in for
        that correction over the calibration samples (`raw_points_fit`) is the
        closer one. Without an estimated correction: ``camera_transform``.
        """
        fit = self.raw_points_fit
        return self.camera_transform if fit is None else self.camera_transform @ fit["transform"]

    @property
    def sigma(self) -> tuple[float, float] | None:
        """Worst-axis 1-sigma of the camera transform from ``cov``: ``(rotation rad, translation m)``, or None.

        The square roots of the largest eigenvalues of the rotation and the
        translation blocks of the 6x6 ``[rotvec, t]`` covariance.
        """
        return None if self.cov is None else worst_axis_sigma(self.cov)

    @property
    def rejected(self) -> np.ndarray:
        """Indices of samples rejected as outliers (empty if none or not robust)."""
        if self.inliers is None:
            return np.zeros(0, dtype=int)
        return np.flatnonzero(~self.inliers)

    def _require(self, setup: Setup, name: str) -> None:
        if self.setup != setup:
            raise AttributeError(f"{name} is defined for setup={setup.value!r}, this result is {str(self.setup)!r}")
