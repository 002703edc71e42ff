"""``solve("auto")``: every measurement the data carry, the extended model of `handeye.calib.model`.

Pipeline (both setups; eye-to-hand ``X = T_flange_marker``, ``Y = T_base_cam``;
eye-in-hand ``X = T_flange_cam``, ``Y = T_base_marker``; paper eq. 1):

1. Start: the best closed form of the paper for the data (YKronT' from the
   marker points; with marker poses also YQuatT' and YKronRT), chosen by the
   median point residual. Pose data first get their half-turn / flip
   ambiguity resolved (`handeye.calib.symmetry`). Motions that leave the split
   between the two translations open (the tool never turns, or turns about
   one axis: `handeye.calib.auto.determined`) start from a registration instead
   (no closed form of the paper can), and every fit holds that part (at a
   given marker offset, else at zero) with a prior; the result names it in
   ``undetermined``. A given marker offset is held whatever the motions.
2. Outliers: if the start's residuals show any (chi-square test at a robust
   scale), the LMedS search of `handeye.calib.robust` around that closed form.
3. Maximum likelihood on the inliers with the extended model: marker points
   (always), marker orientations (pose data), robot pose error propagated
   into the points, and the camera's depth scale / depth offset / focal
   scale (`camera_correction`), in rounds with the variance-component
   estimate of the noise levels (`handeye.calib.model.variance_components`,
   `handeye.calib.auto.fit.fit_components`). Orientations and camera parameters are
   model choices made by held-out error (`handeye.calib.auto.camera.select_camera`);
   the well-determined ones are fitted together, and a choice that a
   Gauss-Newton step already shows to be useless is not refitted
   (`handeye.calib.auto.camera.step_helps`).
   From 100 samples on, those choices are checked on contiguous stretches
   of the recording held out in turn (`handeye.calib.auto.blocked`): a simpler model
   that predicts them at least as well is taken instead, and the closed-form
   start if it predicts them clearly better, so that what is reported
   carries to another session.
4. Camera parameters the motions do not determine (from the information
   matrix: their 1-sigma would exceed `IDENTIFIABLE_SIGMA`) stay at nominal
   (zero), with a message naming the motion that would fix it.
5. Covariance (`handeye.calib.auto.consider` adds what is not estimated) and the
   self-check (`handeye.calib.diagnostics`): chi-square of the residuals against the
   camera's a-priori noise model, and the linearised leave-one-out
   prediction error of the marker point beside the predicted one (the
   hat-matrix formula of `handeye.calib.model.leave_one_out`: no refit, so it runs
   inside every ``solve``).

Modules: `handeye.calib.auto.pipeline` (``solve_auto``, the stages), `handeye.calib.auto.fit`,
`handeye.calib.auto.camera`, `handeye.calib.auto.consider`, `handeye.calib.auto.blocked`,
`handeye.calib.auto.determined`.
"""


from handeye.calib.auto.blocked import blocked_folds
from handeye.calib.auto.camera import CAMERA_CORRECTIONS, MIN_SAMPLES_CAMERA, identifiability
from handeye.calib.auto.consider import CONSIDER_SIGMA
from handeye.calib.auto.pipeline import solve_auto

__all__ = ["CAMERA_CORRECTIONS", "CONSIDER_SIGMA", "MIN_SAMPLES_CAMERA", "blocked_folds", "identifiability",
           "solve_auto"]
