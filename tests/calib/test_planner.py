"""handeye.calib.planner: screening, information ordering, bootstrap safety, both setups."""

import numpy as np
import pytest

from handeye.calib import transforms as tf
from handeye.calib.errors import CalibrationError, ParameterError
from handeye.calib.noise import default_point_cov
from handeye.calib.planner import (
    CameraView,
    KeepOut,
    PlannerConfig,
    PosePlanner,
    bootstrap_poses,
    candidate_poses,
    least_informative,
    marker_rotation,
    travel_time,
)
from handeye.calib.simulate import realistic_cell

VIEW = CameraView(width=640, height=480, fx=570.0, fy=570.0, cx=319.5, cy=239.5, margin_px=40, depth_min_m=0.4, depth_max_m=2.0,
                  max_view_angle_deg=60.0, marker_size_m=0.05)


def _cell(setup, seed=0):
    """True X, Y of `handeye.calib.simulate.realistic_cell` and its start pose (marker and camera facing at 0.7 m)."""
    from scipy.spatial.transform import Rotation

    d = realistic_cell(1, np.random.default_rng(seed), setup=setup)
    flip = Rotation.from_euler("y", np.pi).as_matrix()
    if setup == "eye_to_hand":
        T0 = tf.make_transform(d.Y[:3, :3] @ flip, [0.9, 0.1, 0.5])
    else:
        T0 = d.Y @ tf.invert(tf.make_transform(flip, [0, 0, 0.7])) @ tf.invert(d.X)
    return d.X, d.Y, T0


def _visible_under(setup, X, Y, T):
    """Screen with the true transforms and no uncertainty margin: what the camera would really see."""
    return PosePlanner(setup, X, Y, VIEW, PlannerConfig(uncertainty_k=0)).screen(T)[0]


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_start_pose_sees_the_marker(setup):
    X, Y, T0 = _cell(setup)
    assert _visible_under(setup, X, Y, T0[None])[0]


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_every_planned_pose_is_seen_under_the_truth_from_a_perturbed_estimate(setup):
    """Planning on a rough estimate (3 mm / 0.3 deg off, with the matching uncertainty) keeps the marker in view."""
    X, Y, T0 = _cell(setup)
    rng = np.random.default_rng(1)
    bump = tf.from_rotvec_translation(rng.normal(0, np.deg2rad(0.3), 3), rng.normal(0, 0.003, 3))
    Xe, Ye = (X, bump @ Y) if setup == "eye_to_hand" else (X @ bump, Y)
    cfg = PlannerConfig(translation_range_m=0.15 if setup == "eye_to_hand" else 0.1,
                        tilt_deg=40.0 if setup == "eye_to_hand" else 20.0)
    planner = PosePlanner(setup, Xe, Ye, VIEW, cfg)
    for T in bootstrap_poses(T0, setup, VIEW, planner.marker_in_camera(T0[None])[0, :3, 3], cfg, n=5):
        planner.add(T)
    poses = planner.plan(T0, None, 15, rng)
    assert len(poses) == 15
    A = np.stack([p.T_base_flange for p in poses])
    assert _visible_under(setup, X, Y, A).all()
    # Predicted covariance shrinks monotonically (information only grows).
    logdets = [np.linalg.slogdet(p.cov)[1] for p in poses]
    assert np.all(np.diff(logdets) < 0)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_chosen_pose_gains_more_information_than_random_candidates(setup):
    X, Y, T0 = _cell(setup)
    cfg = PlannerConfig(travel_weight=0.0, uncertainty_k=0, tilt_deg=40 if setup == "eye_to_hand" else 20)
    planner = PosePlanner(setup, X, Y, VIEW, cfg)
    for T in bootstrap_poses(T0, setup, VIEW, planner.marker_in_camera(T0[None])[0, :3, 3], cfg, n=5):
        planner.add(T)
    rng = np.random.default_rng(3)
    chosen = planner.next_pose(T0, T0, None, rng)
    others = candidate_poses(T0, cfg, np.random.default_rng(4))
    ok = planner.screen(others)[0]
    gains = planner.gains(others[ok])
    assert chosen.gain == pytest.approx(planner.gains(chosen.T_base_flange[None])[0])
    assert chosen.gain >= np.quantile(gains, 0.95)
    # And it is a real reduction of the predicted uncertainty.
    before = np.linalg.slogdet(planner.camera_cov())[1]
    assert np.linalg.slogdet(chosen.cov)[1] == pytest.approx(before - chosen.gain)


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
def test_optimal_sequence_beats_random_sequences_on_predicted_sigma(setup):
    X, Y, T0 = _cell(setup)
    cfg = PlannerConfig(uncertainty_k=0, tilt_deg=40 if setup == "eye_to_hand" else 20,
                        translation_range_m=0.15 if setup == "eye_to_hand" else 0.1)
    n = 10

    def worst_sigma(planner):
        cov = planner.camera_cov()
        return np.sqrt(np.linalg.eigvalsh(cov[:3, :3])[-1]), np.sqrt(np.linalg.eigvalsh(cov[3:, 3:])[-1])

    opt = PosePlanner(setup, X, Y, VIEW, cfg)
    opt.plan(T0, None, n, np.random.default_rng(0))
    s_opt = worst_sigma(opt)
    for seed in range(5):
        rnd = PosePlanner(setup, X, Y, VIEW, cfg)
        rng = np.random.default_rng(seed)
        taken = 0
        while taken < n:
            T = candidate_poses(T0, PlannerConfig(n_candidates=1, local_fraction=0, tilt_deg=cfg.tilt_deg,
                                                  translation_range_m=cfg.translation_range_m), rng)
            if rnd.screen(T)[0][0]:
                rnd.add(T[0])
                taken += 1
        s_rnd = worst_sigma(rnd)
        assert s_opt[0] < s_rnd[0] and s_opt[1] < s_rnd[1]


def test_travel_cost_prefers_the_nearer_of_equal_poses():
    cfg = PlannerConfig()
    T0 = np.eye(4)
    far, near = tf.make_transform(np.eye(3), [0.3, 0, 0]), tf.make_transform(np.eye(3), [0.05, 0, 0])
    t = travel_time(T0, np.stack([far, near]), cfg)
    assert t[0] > t[1] > 0
    # 0.3 m at 0.25 m/s, 1 m/s^2: trapezoid 0.3/0.25 + 0.25 = 1.45 s.
    assert t[0] == pytest.approx(1.45)


def test_keep_out_box_on_the_path_rejects_the_candidate():
    X, Y, T0 = _cell("eye_to_hand")
    target = T0.copy()
    target[:3, 3] += [0.0, 0.0, -0.2]
    mid = 0.5 * (T0[:3, 3] + target[:3, 3])
    box = KeepOut(min=tuple(mid - 0.01), max=tuple(mid + 0.01))
    free = PosePlanner("eye_to_hand", X, Y, VIEW, PlannerConfig(uncertainty_k=0))
    blocked = PosePlanner("eye_to_hand", X, Y, VIEW, PlannerConfig(uncertainty_k=0, keep_out=(box,)))
    assert free.screen(target[None], T0)[0][0]
    assert not blocked.screen(target[None], T0)[0][0]
    assert blocked.screen(target[None])[0][0]  # the target alone is clear; the path is not
    assert blocked.stats.reasons["keep-out box"] == 1


def test_screen_rejects_marker_turned_away_and_out_of_range():
    X, Y, T0 = _cell("eye_to_hand")
    planner = PosePlanner("eye_to_hand", X, Y, VIEW, PlannerConfig(uncertainty_k=0))
    flipped = T0.copy()
    flipped[:3, :3] = T0[:3, :3] @ np.diag([1.0, -1.0, -1.0])  # marker faces away
    far = T0.copy()
    far[:3, 3] += 2.0 * (T0[:3, 3] - Y[:3, 3])  # three times as far from the camera
    ok, _, _ = planner.screen(np.stack([T0, flipped, far]))
    assert ok.tolist() == [True, False, False]
    assert planner.stats.reasons["view angle"] == 1 and planner.stats.reasons["depth range"] == 1


def test_uncertainty_widens_the_margin():
    X, Y, T0 = _cell("eye_to_hand")
    edge = T0.copy()
    edge[:3, 3] += 0.12 * Y[:3, 0]  # towards the image border along the camera x axis
    sure = PosePlanner("eye_to_hand", X, Y, VIEW, PlannerConfig(uncertainty_k=0))
    unsure = PosePlanner("eye_to_hand", X, Y, VIEW, PlannerConfig(uncertainty_k=3, prior_sigma_m=0.05,
                                                                     prior_sigma_rad=0.05))
    assert sure.screen(edge[None])[0][0]
    assert not unsure.screen(edge[None])[0][0]


@pytest.mark.parametrize("setup", ["eye_to_hand", "eye_in_hand"])
@pytest.mark.parametrize("seed", range(20))
def test_bootstrap_keeps_the_marker_in_view_for_any_mounting_within_the_lever_bound(seed, setup):
    """The bootstrap is model-free: whatever X (lever <= 10 cm) and Y, its poses keep the marker in view."""
    rng = np.random.default_rng(seed)
    X0, Y0, T0 = _cell(setup)
    R = tf.random_rotations(1, np.pi, rng)[0]
    t = rng.normal(size=3)
    t *= rng.uniform(0, 0.1) / np.linalg.norm(t)
    if setup == "eye_to_hand":
        # Another marker mounting; keep the camera where it sees the marker at the start pose.
        X = tf.make_transform(R, t)
        Y = Y0
        look = tf.invert(Y) @ T0 @ X
        if -look[:3, 2] @ look[:3, 3] < np.cos(np.deg2rad(50)) * np.linalg.norm(look[:3, 3]):
            return  # this mounting faces away from the camera at the start: nothing to bootstrap from
    else:
        X = tf.make_transform(tf.random_rotations(1, 0.3, rng)[0] @ X0[:3, :3], t)
        Y = T0 @ X @ tf.invert(tf.invert(T0 @ X0) @ Y0)
    cfg = PlannerConfig(tilt_deg=40.0, translation_range_m=0.15)
    truth = PosePlanner(setup, X, Y, VIEW, PlannerConfig(uncertainty_k=0))
    first = truth.marker_in_camera(T0[None])[0]
    if not truth.screen(T0[None])[0][0]:
        return
    angle = np.degrees(np.arccos(-first[:3, 2] @ first[:3, 3] / np.linalg.norm(first[:3, 3])))
    B = bootstrap_poses(T0, setup, VIEW, first[:3, 3], cfg, lever_max_m=0.1, view_angle_deg=angle, n=6)
    assert truth.screen(B)[0].all()


def test_bootstrap_bounds_the_turn_of_the_viewing_ray():
    """Regression (bench validity run, seed 0, cell 26): an oblique marker (29.5 deg) off the flange axis.

    The bound used to budget the view angle for the marker's own turn only; the offset also turns the ray
    from the camera, and the second bootstrap pose showed the marker at 60.9 deg (limit 60)."""
    X = tf.make_transform(tf.so3_exp([0.149881, 0.481381, 0.531920]), [0.013413, -0.012891, -0.029743])
    Y = tf.make_transform(tf.so3_exp([-2.003830, 0.280646, -0.176471]), [0.7, -0.6, 0.85])
    T0 = tf.make_transform(tf.so3_exp([-0.216067, -1.542730, 2.453443]), [0.9, 0.1, 0.5])
    truth = PosePlanner("eye_to_hand", X, Y, VIEW.model_copy(update={"margin_px": 0.0}), PlannerConfig(uncertainty_k=0))
    first = truth.marker_in_camera(T0[None])[0]
    angle = np.degrees(np.arccos(-first[:3, 2] @ first[:3, 3] / np.linalg.norm(first[:3, 3])))
    assert 29 < angle < 30
    B = bootstrap_poses(T0, "eye_to_hand", VIEW, first[:3, 3], PlannerConfig(tilt_deg=40.0, translation_range_m=0.15),
                        lever_max_m=0.1, view_angle_deg=angle)
    assert len(B) == 5 and truth.screen(B)[0].all(), dict(truth.stats.reasons)


def test_marker_rotation_recovers_the_flange_marker_rotation():
    d = realistic_cell(8, np.random.default_rng(2))
    X_point_only = tf.make_transform(np.eye(3), d.X[:3, 3])
    X, Y = marker_rotation("eye_to_hand", X_point_only, d.Y, d.A, d.B)
    assert np.degrees(tf.rotation_angle(X[:3, :3].T @ d.X[:3, :3])) < 1.0
    assert np.array_equal(Y, d.Y)


def test_bad_inputs_are_named():
    with pytest.raises(ParameterError, match="margin_px"):
        CameraView(**{**VIEW.model_dump(), "margin_px": 300})
    with pytest.raises(ParameterError, match="CameraView.fx"):
        CameraView(width=640, height=480, fx=True, fy=570, cx=320, cy=240)
    with pytest.raises(ParameterError, match="depth_min_m < depth_max_m"):
        CameraView(width=640, height=480, fx=570, fy=570, cx=320, cy=240, depth_min_m=2.5)
    with pytest.raises(ParameterError, match="CameraView.max_view_angle_deg"):
        CameraView(width=640, height=480, fx=570, fy=570, cx=320, cy=240, max_view_angle_deg=90)
    with pytest.raises(ParameterError, match="PlannerConfig.n_candidates"):
        PlannerConfig(n_candidates=0)
    with pytest.raises(ParameterError, match="PlannerConfig.n_candidates"):
        PlannerConfig(n_candidates=300.0)
    with pytest.raises(ParameterError, match="PlannerConfig.travel_weight"):
        PlannerConfig(travel_weight=float("nan"))
    with pytest.raises(ParameterError, match="PlannerConfig.local_fraction"):
        PlannerConfig(local_fraction=1.5)
    with pytest.raises(ParameterError, match="workspace_min and workspace_max go together"):
        PlannerConfig(workspace_min=(0, 0, 0))
    with pytest.raises(ParameterError, match="KeepOut: min"):
        KeepOut(min=(0, 0, 0), max=(0, 1, 1))
    with pytest.raises(ParameterError, match="PlannerConfig.keep_out.0: min"):
        PlannerConfig(keep_out=[((0, 0, 0), (0, 1, 1))])
    with pytest.raises(ParameterError, match="PlannerConfig.speed_m_s"):
        PlannerConfig(speed_m_s=0)
    assert PlannerConfig(keep_out=[((0, 0, 0), (1, 1, 1))]).keep_out == (KeepOut(min=(0, 0, 0), max=(1, 1, 1)),)
    with pytest.raises(CalibrationError, match="point_cam"):
        bootstrap_poses(np.eye(4), "eye_to_hand", VIEW, [0, 0, -1], PlannerConfig())


def test_bounded_set_keeps_the_informative_samples_of_a_repetitive_production_run():
    """20 varied poses, then 180 samples at 3 production poses: a 40-sample set kept by information
    holds on to the varied ones (and stays well conditioned); a FIFO of 40 forgets them."""
    X, Y, T0 = _cell("eye_to_hand")
    rng = np.random.default_rng(7)
    cfg = PlannerConfig(uncertainty_k=0)
    varied = candidate_poses(T0, cfg, rng)
    varied = varied[PosePlanner("eye_to_hand", X, Y, VIEW, cfg).screen(varied)[0]][:20]
    production = varied[:3] @ tf.from_rotvec_translation(np.zeros(3), [0.002, 0, 0])
    stream = list(varied) + [production[i % 3] for i in range(180)]
    kept: list[int] = []
    for i in range(len(stream)):
        kept.append(i)
        if len(kept) > 40:
            kept.pop(least_informative("eye_to_hand", X, Y, np.array([stream[k] for k in kept]), keep_recent=10))
    assert len(kept) == 40 and kept[-10:] == list(range(190, 200))  # the newest always stay
    assert sum(k < 20 for k in kept) >= 15

    def worst_sigma_mm(indices):
        p = PosePlanner("eye_to_hand", X, Y, VIEW, cfg)
        for k in indices:
            p.add(stream[k])
        return 1e3 * np.sqrt(np.linalg.eigvalsh(p.camera_cov()[3:, 3:])[-1])

    assert worst_sigma_mm(kept) < 0.5 * worst_sigma_mm(range(160, 200))


def test_camera_correction_is_planned_for_when_it_is_estimated():
    """With depth scale and offset free (solve("auto")), the planner's poses pin them down better than
    poses planned for the camera transform alone (mean over seeds, 12 poses)."""
    X, Y, T0 = _cell("eye_to_hand")
    cfg = PlannerConfig(uncertainty_k=0)
    corr = (np.zeros(3), (True, True, False))
    judge = PosePlanner("eye_to_hand", X, Y, VIEW, cfg, correction=corr)
    assert judge.information.shape == (11, 11)
    sig = {True: [], False: []}
    for seed in range(4):
        for aware in (True, False):
            planner = PosePlanner("eye_to_hand", X, Y, VIEW, cfg, correction=corr if aware else None)
            A = np.array([p.T_base_flange for p in planner.plan(T0, None, 12, np.random.default_rng(seed))])
            cov = np.linalg.inv(judge.information + judge.sample_information(A).sum(axis=0))
            sig[aware].append(np.sqrt(np.diag(cov)[9:11]))  # depth scale, depth offset
    assert np.all(np.mean(sig[True], axis=0) < np.mean(sig[False], axis=0))


@pytest.mark.parametrize("n", [8, 16])
def test_predicted_covariance_is_what_auto_reports(n):
    """With the camera corrections as unknowns with handeye.calib.auto's typical errors as priors, the planner predicts
    the camera 1-sigma solve("auto") reports: below MIN_SAMPLES_CAMERA the consider covariance (corrections
    at nominal), from it on the estimated one (synthetic samples at planned poses, 0.3 mm along the ray)."""
    from handeye.calib.api import solve
    from handeye.calib.auto import CONSIDER_SIGMA, MIN_SAMPLES_CAMERA
    from handeye.calib.model import CAMERA_PARAMS
    from handeye.calib.result import worst_axis_sigma

    def quiet(p):
        return 0.01 * default_point_cov(p)

    X, Y, T0 = _cell("eye_to_hand")
    rng = np.random.default_rng(0)
    prior = np.array([CONSIDER_SIGMA[m] for m in CAMERA_PARAMS])
    planner = PosePlanner("eye_to_hand", X, Y, VIEW, PlannerConfig(uncertainty_k=0), quiet,
                          correction=(np.zeros(3), (True, True, True), prior))
    A = np.array([p.T_base_flange for p in planner.plan(T0, None, n, rng)])
    P = (tf.invert(Y) @ A @ X)[:, :3, 3]
    cov = quiet(P)
    measured = P + np.einsum("nij,nj->ni", np.linalg.cholesky(cov), rng.normal(size=P.shape))
    reported = worst_axis_sigma(solve("auto", A, measured, setup="eye_to_hand", point_cov=cov).cov)
    predicted = worst_axis_sigma(planner.consider_cov() if n < MIN_SAMPLES_CAMERA else planner.camera_cov())
    assert np.allclose(predicted, reported, rtol=0.15)
    if n < MIN_SAMPLES_CAMERA:  # the corrections' typical errors dominate: 1 % depth scale is 7 mm at 0.7 m
        assert worst_axis_sigma(planner.camera_cov())[1] < 0.3 * reported[1]
    with pytest.raises(CalibrationError, match="sigma"):
        PosePlanner("eye_to_hand", X, Y, VIEW, correction=(np.zeros(3), (False, True, False), [1, 0, 1]))


def test_anchored_noise_model_keeps_the_default_depth_law_at_the_measured_level():
    from handeye.calib.noise import anchored_point_cov

    p0 = np.array([0.1, -0.05, 0.7])
    S0 = default_point_cov(p0[None])[0]
    points = np.array([[0.2, -0.1, 1.1], [0.0, 0.0, 0.5]])
    assert np.allclose(anchored_point_cov(p0, S0)(points), default_point_cov(points), rtol=1e-9, atol=0)
    assert np.allclose(anchored_point_cov(p0, 0.01 * S0)(points), 0.01 * default_point_cov(points), rtol=1e-9, atol=0)
    with pytest.raises(CalibrationError, match="positive definite"):
        anchored_point_cov(p0, np.zeros((3, 3)))
