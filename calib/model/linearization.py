"""The whitened residual vector and Jacobian of a data set (`Linearization`), its information, and the
Levenberg-Marquardt fit on it."""

from __future__ import annotations

import numpy as np

from handeye.calib import transforms as tf
from handeye.calib.errors import DegenerateMotionError
from handeye.calib.model.correction import measured_points
from handeye.calib.model.frames import split
from handeye.calib.model.prior import TranslationPrior
from handeye.calib.model.residuals import robot_cofactor, rotation_residuals
from handeye.calib.model.weights import NoiseLevels, whitener


#: Smallest eigenvalue ratio of the information before the motions are called degenerate.
MIN_INFORMATION_RATIO = 1e-14


#: ``[e_k]x`` for the unit vectors (3, 3, 3): ``[v]x = sum_k v_k [e_k]x``.
GENERATORS = tf.skew(np.eye(3))


def same_point(a, b) -> bool:
    """Whether two ``(C, K, theta)`` are the same estimate (theta None and zeros differ: different Jacobians)."""
    if (a[2] is None) != (b[2] is None):
        return False
    for x, y in zip(a, b):
        if x is not y and not np.array_equal(x, y):
            return False
    return True


class Linearization:
    """Whitened residual vector and Jacobian of one data set (see the module docstring).

    Parameters
    ----------
    M : ndarray, shape (N, 4, 4)
        Per-sample robot transform of the model (`split`).
    B : ndarray, shape (N, 3) or (N, 4, 4)
        Measured marker points or poses (camera frame).
    W_t : ndarray, shape (N, 3, 3)
        Whitening matrices of the point residual (`whitener` of ``Sigma_i``).
    sigma_rot : float, optional
        Rotation noise (rad) of pose data.
    free : sequence of bool, length 3
        Which of `CAMERA_PARAMS` are estimated; the others stay at ``theta``.
    use_rotation : bool
        Whether pose data contribute their orientation residual (else only
        the translation of ``B`` is used and ``K``'s rotation is not estimated).
    memo : dict, optional
        Shared by problems of the same ``M``, ``B`` and ``use_rotation``
        that differ only in their weights and free camera parameters: `raw`
        keeps its last evaluation there, so re-weighting at a fixed estimate
        (variance components, then the next fit) or freeing another camera
        parameter does not evaluate it twice, and the contiguous copies of
        ``M``'s blocks are made once. The arrays `raw` returns are then
        shared and must not be modified.
    prior : TranslationPrior, optional
        A prior on the translations (`handeye.calib.model.prior`: a known marker
        mount, or what the motions leave open held): its rows join the normal
        matrix, gradient and cost (not `whitened`, which holds the
        measurement rows).
    """

    def __init__(self, M, B, W_t, sigma_rot=None, free=(False, False, False), use_rotation=True, memo=None,
                 prior: TranslationPrior | None = None):
        self.M = M
        self._memo = memo
        self._store = memo if memo is not None else {}     # where `system` keeps its last result
        # Contiguous copies: products with them are single BLAS calls (views of M are strided). Shared through
        # the memo by the re-weighted problems of a fit.
        geometry = None if memo is None else memo.get("geometry")
        if geometry is None:
            geometry = (np.ascontiguousarray(M[:, :3, :3]), np.ascontiguousarray(M[:, :3, 3]),
                        np.ascontiguousarray(np.swapaxes(M[:, :3, :3], 1, 2)))
            if memo is not None:
                memo["geometry"] = geometry
        self._R_M, self._t_M, self._R_Mt = geometry
        self.rotations = B.ndim == 3 and use_rotation
        self.p = B if B.ndim == 2 else B[:, :3, 3]
        self.R_B = B[:, :3, :3] if self.rotations else None
        self.W_t = W_t
        self.sigma_rot = sigma_rot
        self.free = np.asarray(free, dtype=bool)
        self._key = tuple(bool(f) for f in self.free)      # memo key of this free set
        self.n_pose = 12 if self.rotations else 9
        self.n_params = self.n_pose + int(self.free.sum())
        self.prior = prior
        self._prior_J = None if prior is None else prior.jacobian(self.n_pose, self.n_params)

    @property
    def points(self) -> bool:
        """True when only marker points are used (no orientation residual)."""
        return not self.rotations

    def raw(self, C, K, theta=None):
        """Unwhitened residuals and Jacobians: ``r (N,3), e (N,3)|None, J_t (N,3,P), J_e (N,3,P)|None``."""
        if self._memo is None:
            return self._raw(C, K, theta, self.free)[0]
        # Kept per free set at the last estimate; another free set there takes the residuals and the pose
        # columns (they do not depend on which camera parameters are free) and adds its camera columns.
        last = self._memo.get("raw")
        if last is None or not same_point(last[0], (C, K, theta)):
            out, q = self._raw(C, K, theta, self.free)
            last = ((C, K, theta), {}, q)
            self._memo["raw"] = last
        else:
            out = last[1].get(self._key)
            if out is None:
                r, e, J_t, J_e = next(iter(last[1].values()))
                n, n_pose = len(r), self.n_pose
                J_t2 = np.empty((n, 3, self.n_params))
                J_t2[:, :, :n_pose] = J_t[:, :, :n_pose]
                self._camera_columns(last[2], theta, self.free, J_t2[:, :, n_pose:])
                J_e2 = None
                if J_e is not None:
                    J_e2 = np.zeros((n, 3, self.n_params))
                    J_e2[:, :, :n_pose] = J_e[:, :, :n_pose]
                out = (r, e, J_t2, J_e2)
        last[1][self._key] = out
        return out

    @staticmethod
    def _camera_columns(q, theta, free, out) -> None:
        """Jacobian columns ``out`` (N, 3, k) of the point residual w.r.t. the ``free`` camera parameters at the
        uncorrected points ``q`` (N, 3) (zero without ``theta``): minus ``dh/dtheta`` of `measure`."""
        if theta is None:
            out[...] = 0.0
            return
        s, d, f = theta
        z = q[:, 2]
        Dq = q * np.array([1.0 + f, 1.0 + f, 1.0])
        for k, j in enumerate(np.flatnonzero(free)):
            if j == 0:
                np.negative(Dq, out=out[:, :, k])
            elif j == 1:
                np.divide(Dq, -z[:, None], out=out[:, :, k])
            else:
                out[:, :, k] = -(q * (1.0 + s + d / z)[:, None] * np.array([1.0, 1.0, 0.0]))

    def _columns(self, J) -> np.ndarray:
        """The columns of this problem's parameters from a Jacobian with every camera parameter, contiguous
        (an index array on the last axis leaves it outermost in memory, which slows the products with it)."""
        out = np.empty(J.shape[:2] + (self.n_params,))
        out[:, :, :self.n_pose] = J[:, :, :self.n_pose]
        out[:, :, self.n_pose:] = J[:, :, self.n_pose + np.flatnonzero(self.free)]
        return out

    def _raw(self, C, K, theta, free):
        """`raw` for the camera parameters ``free``, and the points without camera error ``q`` (N, 3)."""
        R_C, t_C = C[:3, :3], C[:3, 3]
        n, n_pose = len(self._R_M), self.n_pose
        n_params = n_pose + int(free.sum())
        # Marker center minus camera origin, C's parent frame, as one matrix-vector product over all samples.
        w = (self._R_M.reshape(-1, 3) @ K[:3, 3]).reshape(n, 3) + (self._t_M - t_C)
        q = w @ R_C                                       # == (R_C^T w_i)_i, the point without camera error
        tK = 9 if self.rotations else 6
        # Filled in place (no concatenation): [dC, tC, (dK), tK, nuisances]. Blocks as single matrix
        # products instead of batched 3x3 ones: -R_C^T [w]x = -[q]x R_C^T = -sum_k q_k [e_k]x R_C^T, and
        # (R_C^T R_M)^T = R_M^T R_C.
        Jp = np.empty((n, 3, n_pose))
        Jp[:, :, 0:3] = (q @ -(GENERATORS @ R_C.T).reshape(3, 9)).reshape(n, 3, 3)
        Jp[:, :, 3:6] = R_C.T
        if self.rotations:
            Jp[:, :, 6:9] = 0.0
        Jp[:, :, tK:tK + 3] = np.swapaxes((self._R_Mt.reshape(-1, 3) @ -R_C).reshape(n, 3, 3), 1, 2)
        if not (theta is not None and (np.any(theta) or free.any())):
            r = self.p - q
            if not free.any():
                return ((r, None, Jp, None) if not self.rotations else (r, *self._rotation_part(C, K, Jp))), q
            J_t = np.zeros((n, 3, n_params))
            J_t[:, :, :n_pose] = Jp
        else:
            s, d, f = theta
            z = q[:, 2]
            g = 1.0 + s + d / z
            D = np.array([1.0 + f, 1.0 + f, 1.0])
            Dq = D * q
            r = self.p - Dq * g[:, None]
            # J_p = g diag(D) + c e_z^T with c = -(D q) d / z^2 (`measure`), built as rows (N, 9); one batched
            # product into place (cheaper than broadcasting over the 3-long axis).
            J_p = np.zeros((n, 9))
            J_p[:, ::4] = g[:, None] * D
            J_p[:, 2::3] += Dq * (-d / z**2)[:, None]
            J_t = np.empty((n, 3, n_params))
            np.matmul(J_p.reshape(n, 3, 3), Jp, out=J_t[:, :, :n_pose])
            self._camera_columns(q, theta, free, J_t[:, :, n_pose:])
        if not self.rotations:
            return (r, None, J_t, None), q
        return (r, *self._rotation_part(C, K, J_t)), q

    def _rotation_part(self, C, K, J_t):
        """``e, J_t, J_e`` of `raw`: the orientation residuals and their Jacobian (`rotation_residuals`)."""
        e, JeC, JeK = rotation_residuals(C, K, self.M, self.R_B)
        J_e = np.zeros_like(J_t)
        J_e[:, :, 0:3] = JeC
        J_e[:, :, 6:9] = JeK
        return e, J_t, J_e

    def system(self, C, K, theta):
        """``raw``, the whitened point residuals ``v`` (N, 3) and Jacobian ``G`` (N, 3, P), ``G^T G`` and the
        normal matrix (with the orientation rows).

        The last one is kept (in the memo when there is one): a fit's last step, the variance components
        and the information at one estimate with one whitening share it.
        """
        raw = self.raw(C, K, theta)
        key = self._key
        last = self._store.get("system")
        if last is None or not (last[0] is self.W_t and same_point(last[1], (C, K, theta))
                                and last[2] == self.sigma_rot):
            last = (self.W_t, (C, K, theta), self.sigma_rot, {})
            self._store["system"] = last
        systems = last[3]
        if key in systems:
            return systems[key]
        full = systems.get((True, True, True))
        if full is not None:
            # Fewer camera parameters free at the same estimate and whitening: their rows and columns.
            cols = np.concatenate([np.arange(self.n_pose), self.n_pose + np.flatnonzero(self.free)])
            out = (raw, full[1], self._columns(full[2]), full[3][cols][:, cols], full[4][cols][:, cols])
        else:
            r, e, J_t, J_e = raw
            v = np.einsum("nij,nj->ni", self.W_t, r)
            G = self.W_t @ J_t
            G_flat = G.reshape(-1, self.n_params)
            N_points = G_flat.T @ G_flat
            N = N_points
            if self.rotations:
                Je_flat = J_e.reshape(-1, self.n_params)
                N = N + Je_flat.T @ Je_flat / self.sigma_rot**2
            if self.prior is not None:
                N = N + self._prior_J.T @ self._prior_J
            out = (raw, v, G, N_points, N)
        systems[key] = out
        return out

    def normal_equations(self, C, K, theta):
        """Normal matrix ``J^T J``, gradient ``J^T r`` and cost ``r^T r`` of the whitened problem (with the prior)."""
        (r, e, _, J_e), v, G, _, N = self.system(C, K, theta)
        v_flat = v.reshape(-1)
        g = G.reshape(-1, self.n_params).T @ v_flat
        cost = float(v_flat @ v_flat)
        if self.rotations:
            s2 = self.sigma_rot**2
            g = g + J_e.reshape(-1, self.n_params).T @ e.reshape(-1) / s2
            cost += float(np.sum(e * e)) / s2
        if self.prior is not None:
            rp = self.prior.residual(C, K)
            g = g + self._prior_J.T @ rp
            cost += float(rp @ rp)
        return N, g, cost

    def whitened(self, C, K, theta=None):
        """Whitened residual vector (3N or 6N,) and Jacobian (3N or 6N, n_params) of the measurements (no prior rows)."""
        (_, e, _, J_e), v, G, _, _ = self.system(C, K, theta)
        rw = v.reshape(-1)
        Jw = G.reshape(-1, self.n_params)
        if self.rotations:
            rw = np.concatenate([rw, (e / self.sigma_rot).reshape(-1)])
            Jw = np.concatenate([Jw, (J_e / self.sigma_rot).reshape(-1, self.n_params)])
        return rw, Jw

    def cost(self, C, K, theta=None) -> float:
        """Whitened residual square sum (chi-square statistic), the prior's included."""
        last = self._store.get("system")
        if (last is not None and self._key in last[3] and last[0] is self.W_t and last[2] == self.sigma_rot
                and same_point(last[1], (C, K, theta))):
            return self.normal_equations(C, K, theta)[2]      # evaluated at this estimate already
        q = ((self._R_M.reshape(-1, 3) @ K[:3, 3]).reshape(-1, 3) + (self._t_M - C[:3, 3])) @ C[:3, :3]
        p = q if theta is None or not np.any(theta) else measured_points(q, np.asarray(theta, dtype=float))
        r = np.einsum("nij,nj->ni", self.W_t, self.p - p)
        cost = float(np.sum(r * r))
        if self.rotations:
            E = np.swapaxes(self.R_B, 1, 2) @ C[:3, :3].T @ self.M[:, :3, :3] @ K[:3, :3]
            cost += float(np.sum(tf.so3_log(E) ** 2)) / self.sigma_rot**2
        if self.prior is not None:
            rp = self.prior.residual(C, K)
            cost += float(rp @ rp)
        return cost

    def retract(self, C, K, theta, delta):
        """Apply a parameter step with left perturbations: new ``(C, K, theta)``."""
        C2 = tf.make_transform(tf.so3_exp(delta[:3]) @ C[:3, :3], C[:3, 3] + delta[3:6])
        if self.rotations:
            K2 = tf.make_transform(tf.so3_exp(delta[6:9]) @ K[:3, :3], K[:3, 3] + delta[9:12])
        else:
            K2 = tf.make_transform(K[:3, :3], K[:3, 3] + delta[6:9])
        if theta is not None and self.free.any():
            theta = np.array(theta, dtype=float)
            theta[self.free] += delta[self.n_pose:]
        return C2, K2, theta


class WeightedData:
    """One data set under the extended model, with the weights of its current noise levels kept.

    ``M`` (`split`), the camera's point covariance shape ``S_i``, whether
    orientations are used, and caches: the robot cofactor at the last estimate
    and the whitener of the last noise levels, so that re-weighting at a fixed
    estimate (variance components, then the next fit) computes neither again.
    Used by `handeye.calib.auto` and `handeye.calib.diagnostics`.

    Parameters
    ----------
    A : ndarray, shape (N, 4, 4)
        ``T_base_flange``.
    B : ndarray, shape (N, 3) or (N, 4, 4)
        Marker points or ``T_cam_marker``.
    setup : {"eye_to_hand", "eye_in_hand"}
    shape : ndarray, shape (N, 3, 3)
        The camera's point covariance shape (`point_shape`).
    use_rotation : bool
        Whether orientation residuals are used (pose data).
    shape_whitener : ndarray, shape (N, 3, 3), optional
        `whitener` of ``shape`` when the caller has it.
    prior : TranslationPrior, optional
        A prior on the translations every `linearize` carries (`handeye.calib.model.prior`).
    """

    def __init__(self, A, B, setup, shape, use_rotation, shape_whitener=None, prior: TranslationPrior | None = None):
        self.setup = setup
        self.A, self.B = A, B
        self.shape = shape
        self.use_rotation = use_rotation
        self.prior = prior
        self.M = split(np.eye(4), np.eye(4), A, setup)[2]
        self._cof_at = None
        self._memo: dict = {}      # the last raw evaluation, shared by the problems of this data set (`Linearization`)
        self._whitener_at = None   # the last point whitener, with its noise levels and robot cofactor
        self._shape_whitener = shape_whitener

    @property
    def points(self) -> np.ndarray:
        """Marker points (N, 3), m."""
        return self.B if self.B.ndim == 2 else self.B[:, :3, 3]

    def cofactor(self, C, K):
        """`robot_cofactor` at ``(C, K)``; the last one is kept (rounds re-weight at a fixed estimate)."""
        if self._cof_at is None or not ((self._cof_at[0] is C or np.array_equal(self._cof_at[0], C))
                                        and (self._cof_at[1] is K or np.array_equal(self._cof_at[1], K))):
            self._cof_at = (C, K, robot_cofactor(C, K, self.M, self.setup))
        return self._cof_at[2]

    @property
    def shape_whitener(self) -> np.ndarray:
        """`whitener` of the camera's point covariance shape alone (no robot error)."""
        if self._shape_whitener is None:
            self._shape_whitener = whitener(self.shape)
        return self._shape_whitener

    def linearize(self, C, K, noise: NoiseLevels, free):
        """The whitened `Linearization` at ``(C, K)`` with the noise levels ``noise`` and the camera parameters
        ``free``, and the robot cofactor used."""
        cof = self.cofactor(C, K)
        # The same levels at the same estimate (a fit's final problem, its information, its held-out step).
        if self._whitener_at is None or self._whitener_at[0] != noise or self._whitener_at[1] is not cof:
            self._whitener_at = (noise, cof, whitener(noise.point_cov(self.shape, cof)))
        W = self._whitener_at[2]
        return Linearization(self.M, self.B, W, sigma_rot=noise.rotation, free=free, use_rotation=self.use_rotation,
                             memo=self._memo, prior=self.prior), cof


def information(problem: Linearization, C, K, theta=None) -> np.ndarray:
    """Fisher information ``J^T W J`` (n_params, n_params) of ``problem`` at ``(C, K, theta)``."""
    return problem.system(C, K, theta)[4]


def camera_block(info) -> np.ndarray:
    """6x6 camera block of the inverse information, after a degeneracy check."""
    ev = np.linalg.eigvalsh(info)
    if ev[0] <= MIN_INFORMATION_RATIO * ev[-1]:
        raise DegenerateMotionError(
            "the motions do not constrain every unknown "
            f"(Fisher information eigenvalue ratio {ev[0] / ev[-1]:.1e}); vary the flange rotation"
        )
    cov = np.linalg.inv(info)[:6, :6]
    return 0.5 * (cov + cov.T)


def minimize(problem: Linearization, C, K, theta=None, *, max_iterations: int = 50, tol: float = 1e-10):
    """Levenberg-Marquardt on the whitened cost over ``(C, K, theta)``.

    Returns ``C, K, theta, cost, iterations, converged``.
    """
    if max_iterations < 1:
        return C, K, theta, problem.cost(C, K, theta), 0, False
    cost = None
    lam = 1e-6
    for it in range(1, max_iterations + 1):
        H, g, cost_here = problem.normal_equations(C, K, theta)
        if cost is None:
            cost = cost_here          # the starting cost; later ones come from the accepted steps
        while True:
            try:
                delta = -np.linalg.solve(H + lam * np.diag(np.diag(H)), g)
            except np.linalg.LinAlgError:
                raise DegenerateMotionError("the motions do not constrain every unknown (singular normal equations)") from None
            if np.abs(delta).max() < tol:
                # At the minimum to the tolerance: a step this small need not lower the cost (rounding), and
                # raising the damping until it does cost up to 16 more evaluations.
                return C, K, theta, cost, it, True
            C2, K2, theta2 = problem.retract(C, K, theta, delta)
            # The whole system at the trial estimate: a step is usually taken, and the next iteration (or the
            # variance components after it, `handeye.calib.auto`) needs it there; a rejected one costs the Jacobian.
            cost2 = problem.normal_equations(C2, K2, theta2)[2]
            if cost2 <= cost:
                break
            lam *= 10.0
            if lam > 1e10:
                # No descent direction left: we sit at the minimum to numerical precision.
                return C, K, theta, cost, it, True
        lam = max(lam / 10.0, 1e-12)
        step = np.abs(delta).max()
        rel = (cost - cost2) / max(cost, 1e-300)
        C, K, theta, cost = C2, K2, theta2, cost2
        if step < tol or rel < 1e-14:
            return C, K, theta, cost, it, True
    return C, K, theta, cost, max_iterations, False
