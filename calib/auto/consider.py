"""``auto``'s "consider" covariances: what errors it does not estimate add to the camera transform's covariance.
"""

from __future__ import annotations

import numpy as np

from handeye.calib import model
from handeye.calib import transforms as tf
from handeye.calib.auto.fit import Candidate

#: Systematic camera errors assumed for a parameter left at nominal, 1-sigma: they widen the
#: covariance of the result ("consider" covariance) instead of being silently taken as zero.
#: Structured-light figures before an infield correction: 1% scale, 3 mm offset, 1% focal.
CONSIDER_SIGMA = {"depth_scale": 0.01, "depth_offset": 0.003, "focal_scale": 0.01}


def camera_consider(best: Candidate, free, data_sigma) -> np.ndarray:
    """Covariance of the pose unknowns (n_pose, n_pose; the camera transform first, 6) added by the camera
    parameters left at nominal ("consider" covariance).

    They are not estimated, but a real camera has such errors: the estimate
    moves by ``S dtheta_c`` with ``S = -N_xx^-1 N_xc`` for an error
    ``dtheta_c``, so ``S diag(sigma_c^2) S^T`` joins the covariance, with
    ``sigma_c`` the typical error (`CONSIDER_SIGMA`) or, if smaller, what the
    data bound it to (``data_sigma``: 1-sigma with the parameter free; it was
    left out because estimating it did not predict better).
    """
    info, n_pose = best.information((True, True, True))
    x = np.r_[np.arange(n_pose), n_pose + np.flatnonzero(free)]
    c = n_pose + np.flatnonzero(~free)
    S = np.linalg.solve(info[np.ix_(x, x)], info[np.ix_(x, c)])[:n_pose]
    names = [model.CAMERA_PARAMS[i - n_pose] for i in c]
    sig = np.array([min(CONSIDER_SIGMA[m], data_sigma.get(m, np.inf)) for m in names])
    out = (S * sig**2) @ S.T
    return 0.5 * (out + out.T)


def shared_robot_consider(best: Candidate, info, F) -> np.ndarray:
    """Camera covariance (6, 6) added by a robot error that all samples share (``F``: (N, 6, P), `solve_auto`).

    The estimate responds linearly to a change ``dv`` of the whitened
    residuals: ``dx = N^-1 G^T dv`` (``N`` the information, ``G`` the
    whitened Jacobian). Column ``k`` of ``F`` moves every flange pose by
    ``Exp(F_i[:, k])``, the residuals by ``dv_k`` (central differences), so
    ``S S^T`` with ``S = N^-1 G^T [dv_1 .. dv_P]`` joins the covariance: the
    error does not average out over the samples as white noise would.
    """
    fit, prob, C, K, theta = best.fit, best.prob, best.C, best.K, best.theta
    X, Y = model.join(C, K, fit.setup)
    _, G = prob.whitened(C, K, theta)
    h = 1e-3                      # of each 1-sigma column: the response is linear at this scale
    dv = np.empty((G.shape[0], F.shape[2]))
    twist = np.array([h, -h])[:, None, None, None] * np.swapaxes(F, 1, 2)[None]     # (side, N, P, 6)
    moved = fit.A[None, :, None] @ tf.make_transform(tf.so3_exp(twist[..., :3]), twist[..., 3:])  # (2, N, P, 4, 4)
    for k in range(F.shape[2]):
        sides = []
        for side in range(2):
            M_k = model.split(X, Y, moved[side, :, k], fit.setup)[2]
            p = model.predict_points(C, K[:3, 3], M_k, theta)
            v = -np.einsum("nij,nj->ni", prob.W_t, p).reshape(-1)      # the whitened residual, less W p_measured
            if prob.rotations:
                v = np.concatenate([v, (model.rotation_residuals(C, K, M_k, prob.R_B)[0] / prob.sigma_rot).reshape(-1)])
            sides.append(v)
        dv[:, k] = (sides[0] - sides[1]) / (2 * h)
    S = np.linalg.solve(info, G.T @ dv)[:6]
    out = S @ S.T
    return 0.5 * (out + out.T)
