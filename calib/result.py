"""The result of a calibration: the paper's X and Y, named frames, statistics.

Covariance convention (used everywhere in handeye): a 6-vector
``[delta_rotvec (rad), delta_t (m)]`` with ``R_true = Exp(delta_rotvec) @ R_est``
and ``t_true = t_est + delta_t``; ``cov`` is its 6x6 covariance for the
*camera* transform (``T_base_cam`` eye-to-hand, ``T_flange_cam`` eye-in-hand).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from handeye.calib.errors import DegenerateMotionError
from handeye.calib.model import CameraCorrection, NoiseLevels
from handeye.calib.setup import Setup


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
class SelfCheck:
    """Consistency of a calibration with the measurement model (`handeye.calib.diagnostics.self_check`).

    Attributes
    ----------
    chi2, dof, p_value : float, int, float
        The point residuals whitened by the camera's a-priori covariance, no robot error.
    prior_model_rejected : bool
        ``p_value`` below `handeye.calib.diagnostics.CHI2_ALPHA`: the camera noise alone does not explain the residuals.
    loo_observed_m, loo_predicted_m : float
        RMS linearised leave-one-out prediction error of the marker point, observed and predicted by the model, m.
    loo_ratio : float
        Observed / predicted.
    loo_errors_m : ndarray, shape (N,)
        Held-out prediction error per sample, m.
    warning : str or None
        Plain words when the ratio is outside the tolerance.
    """

    chi2: float
    dof: int
    p_value: float
    prior_model_rejected: bool
    loo_observed_m: float
    loo_predicted_m: float
    loo_ratio: float
    loo_errors_m: np.ndarray
    warning: str | None

    @property
    def consistent(self) -> bool:
        return self.warning is None


@dataclass(frozen=True)
class RobustDetails:
    """What the LMedS search of `handeye.calib.robust.robust_solve` did: subsets tried, their size, the robust
    scale of the squared Mahalanobis residuals and the inlier threshold on them."""

    trials: int
    subset: int
    scale: float
    threshold: float


@dataclass(frozen=True)
class RefineDetails:
    """The maximum-likelihood refinement of `handeye.calib.refine.refine`: chi-square at the start and at the end;
    for point data the a posteriori variance factor, for pose data the estimated rotation noise (rad) and
    the scale of the translation covariance."""

    cost: float
    initial_cost: float
    variance_factor: float | None = None
    sigma_rotation: float | None = None
    translation_scale: float | None = None


@dataclass(frozen=True)
class CameraParameter:
    """One camera parameter of ``auto``'s correction (`handeye.calib.model.CAMERA_PARAMS`): value, 1-sigma
    (0 when not estimated) and whether it was estimated (else it stays at nominal, 0). SI units
    (scales as fractions, the depth offset in m)."""

    value: float
    sigma: float
    estimated: bool


@dataclass(frozen=True)
class BlockedCandidate:
    """One model judged on contiguous stretches of the recording held out in turn: the closed form
    ``closed_form`` solved again, or a maximum-likelihood fit with or without the marker orientations and
    with the camera parameters ``camera_correction``; ``heldout_m`` is its RMS point prediction error."""

    heldout_m: float
    closed_form: str | None = None
    orientations: bool | None = None
    camera_correction: tuple[str, ...] = ()


@dataclass(frozen=True)
class BlockedFolds:
    """``auto``'s check of its model choice on blocked folds: the number of folds, every candidate, what
    decided (``chosen_by``) and the held-out error of the model reported (``reported_m``, m; None when the
    stretches did not determine the models)."""

    folds: int
    chosen_by: str
    candidates: tuple[BlockedCandidate, ...]
    reported_m: float | None = None


@dataclass(frozen=True)
class AutoDetails:
    """How ``solve("auto")`` reached its result.

    Attributes
    ----------
    start : str
        The closed form it started from, or ``"registration"`` (`handeye.calib.auto.determined.held_start`) when
        the motions leave part of the translations open (``"+LMedS"`` when the outlier search ran).
    start_candidates : dict of str to float
        Each closed form tried and its median point residual, m.
    measurements : tuple of str
        ``("points",)`` or ``("points", "orientations")``.
    camera_correction : dict of str to CameraParameter
        Per `handeye.calib.model.CAMERA_PARAMS`.
    correction_points : ndarray, shape (M, 3), or None
        The raw points the correction was estimated on (None without a correction).
    noise : handeye.calib.model.NoiseLevels
        Estimated noise levels.
    robot_shared_error_m : float or None
        The 1-sigma of the camera translation that the robot's shared error adds (m), None without it.
    blocked_folds : BlockedFolds or None
        The blocked-fold check (None when not run).
    notes : tuple of str
        Decisions and warnings, in plain words.
    flips : dict or None
        `handeye.calib.symmetry.resolve_flips`' report for pose data.
    cost : float
        Final whitened chi-square.
    """

    start: str
    start_candidates: dict
    measurements: tuple[str, ...]
    camera_correction: dict
    correction_points: np.ndarray | None
    noise: NoiseLevels
    robot_shared_error_m: float | None
    blocked_folds: BlockedFolds | None
    notes: tuple[str, ...]
    flips: dict | None
    cost: float


@dataclass(frozen=True)
class Accuracy:
    """The predicted error of a camera transform over the workspace (`handeye.calib.verdict.workspace_accuracy`).

    The workspace is where the calibration samples put the marker: the error of a
    marker point the camera measures there, mapped into the camera's parent frame
    (the base frame eye-to-hand, the flange frame eye-in-hand), camera correction included.

    Attributes
    ----------
    rms_mm : float
        RMS over the workspace of the point's 1-sigma error (3D), mm: what a verification
        on fresh poses there should find, noise removed.
    p95_mm : float
        At most this error at 95 % anywhere in the workspace, mm (1.96 times the largest
        point's 3D RMS error: a bound for a Gaussian error of any shape).
    rms_deg, p95_deg : float
        The same for the camera's rotation, deg.
    """

    rms_mm: float
    p95_mm: float
    rms_deg: float
    p95_deg: float


#: Verdict levels, from best to worst.
LEVELS = ("pass", "warn", "fail")


@dataclass(frozen=True)
class Verdict:
    """Whether to use a result, in the words of the person who acts on it (`handeye.calib.verdict`).

    Attributes
    ----------
    level : {"pass", "warn", "fail"}
        ``pass``: within the tolerance, nothing to check; ``warn``: usable once the reasons are
        checked; ``fail``: do not use as it is.
    summary : str
        One sentence: the level's meaning and the predicted (or verified) error against the tolerance.
    reasons : tuple of str
        One plain sentence per problem, each with what to do about it (empty for ``pass``).
    """

    level: str
    summary: str
    reasons: tuple[str, ...] = ()

    def __post_init__(self):
        if self.level not in LEVELS:
            raise ValueError(f"verdict level must be one of {LEVELS}, got {self.level!r}")

    def to_dict(self) -> dict:
        """``{level, summary, reasons: [...]}``, as result.yaml and verify.yaml hold it."""
        return {"level": self.level, "summary": self.summary, "reasons": list(self.reasons)}


@dataclass(frozen=True)
class CalibrationResult:
    """Solution of ``A_i X = Y B_i`` (paper eq. 1) and how much to trust it.

    ``X`` and ``Y`` are the paper's unknowns. Eye-to-hand: ``X = T_flange_marker``,
    ``Y = T_base_cam``. Eye-in-hand: ``X = T_flange_cam``, ``Y = T_base_marker``.
    The point-only method (YKronT') recovers only the translation of the
    marker-side transform and reports identity for its rotation
    (``marker_rotation_known`` is False).

    ``undetermined`` names, in plain sentences, what the samples leave open
    and the motion (or the known value) that closes it; empty when they
    determine everything. ``auto`` fills it when the tool never turned or
    turned about one axis only (`handeye.calib.auto.determined`): the open part is
    then held at a stated value, and ``X``, ``Y`` and ``cov`` are the
    determined answer given it. ``accuracy`` and
    ``verdict``: the predicted error over the workspace and whether to use the result against a
    tolerance, set by `handeye.calib.verdict.judge` (None until judged).
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
    cov_kind: str | None = None
    self_check: SelfCheck | None = None
    robust: RobustDetails | None = None
    refinement: RefineDetails | None = None
    auto: AutoDetails | None = None
    undetermined: tuple[str, ...] = ()
    accuracy: Accuracy | None = None
    verdict: Verdict | None = None

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
        """The camera's systematic error the solver estimated (`handeye.calib.model.CameraCorrection`; all zero if
        none).

        ``auto`` estimates it (``auto.camera_correction``); the paper's methods do not.
        """
        cc = {} if self.auto is None else self.auto.camera_correction
        return CameraCorrection(**{name: c.value for name, c in cc.items() if c.estimated})

    @cached_property
    def raw_points_fit(self) -> dict | None:
        """The rigid stand-in for the estimated camera correction, or None without one.

        ``{"transform": G, "misfit_m": rms}``: `handeye.calib.model.CameraCorrection.rigid_stand_in`
        of `camera_correction` over the points it was estimated on
        (``auto.correction_points``, the raw points of the samples in the
        fit). Computed when first asked (the exports ask), not by the solver.
        """
        points = None if self.auto is None else self.auto.correction_points
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
