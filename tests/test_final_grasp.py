"""The refined final grasp (retarget.final_grasp): its change of the last step, the blend into the approach,
the search on objectives whose optimum is known, and the expected quality it maximises (pbdgrasp.strategy)."""

from __future__ import annotations

import numpy as np
import pytest

from assets import sah
from assets import se3 as lie
from assets.errors import InputError
from planning.autograsp import HandCloser
from retarget.final_grasp import (
    FLEXION_JOINTS,
    FinalGraspConfig,
    blend_final_change,
    final_configuration,
    refine_final_grasp,
)

#: How close the search comes to a known optimum: wrist position [m], angles [rad].
OPT_TOL_M = 5e-4
OPT_TOL_RAD = 5e-3
#: Epsilon of draws within ~1e-6 (m, rad) of a configuration against epsilon at it (the closing bisects).
EPS_NEAR_TOL = 1e-4


def _trajectory(n: int = 12):
    s = np.linspace(0.0, 1.0, n)[:, None]
    T = lie.se3_exp(np.array([0.3, -0.2, 0.1, 0.0, 0.05, -0.25]) * (1.0 - 0.3 * s))
    joints = sah.rest_joints() + 0.5 * s * FLEXION_JOINTS
    joints[:, 0] = np.deg2rad(60.0)
    return T, sah.clip_joints(joints)


def test_final_configuration_moves_the_wrist_the_thumb_and_the_flexion_joints():
    T, joints = _trajectory()
    x = np.array([0.01, -0.02, 0.03, 0.004, -0.005, 0.006, 0.1, -0.2])
    T_new, j_new = final_configuration(T[-1], joints[-1], x)
    np.testing.assert_allclose(T_new, T[-1] @ lie.se3_exp(x[:6]), atol=1e-15)
    expected = joints[-1].copy()
    expected[sah.JOINT_NAMES.index("thumb_base")] += 0.1
    expected[FLEXION_JOINTS] -= 0.2
    np.testing.assert_array_equal(j_new, sah.clip_joints(expected))
    abduction = [sah.JOINT_NAMES.index(f"{f}_abd") for f in sah.FINGERS]
    np.testing.assert_array_equal(j_new[abduction], joints[-1][abduction])  # the aperture flexes only
    assert FLEXION_JOINTS.sum() == 8


def test_the_blend_reaches_the_new_last_step_along_a_minimum_jerk_weight():
    T, joints = _trajectory()
    x = np.array([0.0, 0.05, 0.0, 0.01, -0.02, 0.0, 0.05, -0.1])
    T_end, j_end = final_configuration(T[-1], joints[-1], x)
    T_out, j_out = blend_final_change(T, joints, T_end, j_end, steps=4)
    np.testing.assert_array_equal(T_out[:-4], T[:-4])  # before the window: bit for bit
    np.testing.assert_array_equal(j_out[:-4], joints[:-4])
    np.testing.assert_array_equal(T_out[-1], T_end)
    np.testing.assert_array_equal(j_out[-1], j_end)
    # the window's second step sits at s = 1/2, where the minimum-jerk weight is exactly 1/2
    dp = T_end[:3, 3] - T[-1, :3, 3]
    np.testing.assert_allclose(T_out[-3, :3, 3] - T[-3, :3, 3], 0.5 * dp, atol=1e-15)
    dtheta = lie.so3_log(T_end[:3, :3] @ T[-1, :3, :3].T)
    turn = lie.so3_log(T_out[-3, :3, :3] @ T[-3, :3, :3].T)
    np.testing.assert_allclose(turn, 0.5 * dtheta, atol=1e-12)
    np.testing.assert_allclose(
        j_out[-3], sah.clip_joints(joints[-3] + 0.5 * (j_end - joints[-1])), atol=1e-15
    )
    w = [np.linalg.norm(T_out[k, :3, 3] - T[k, :3, 3]) / np.linalg.norm(dp) for k in range(-4, 0)]
    assert np.all(np.diff(w) > 0) and w[0] == pytest.approx(0.25**3 * (10 - 15 * 0.25 + 6 * 0.25**2))


def _peaked_at(T_end, j_end, x_star):
    """An expected quality peaked (value 0.2) at the change ``x_star``: a smooth bump in the wrist position,
    the rotation, the thumb and the aperture."""
    T_star, j_star = final_configuration(T_end, j_end, x_star)

    def quality(T, joints):
        dp = np.linalg.norm(T[:3, 3] - T_star[:3, 3]) / 0.01
        dr = np.linalg.norm(lie.so3_log(T[:3, :3] @ T_star[:3, :3].T)) / 0.05
        dj = np.linalg.norm(joints - j_star) / 0.1
        return 0.2 * np.exp(-(dp**2) - dr**2 - dj**2)

    return quality


def test_refine_finds_a_known_optimum_inside_the_trust_region():
    T, joints = _trajectory()
    x_star = np.array([0.02, -0.03, 0.01, 0.008, -0.012, 0.005, 0.08, -0.15])
    res = refine_final_grasp(T, joints, _peaked_at(T[-1], joints[-1], x_star), FinalGraspConfig(max_nfev=800))
    assert res.kept and res.quality_after == pytest.approx(0.2, abs=1e-3) and res.quality_before < 0.01
    T_found, _ = final_configuration(T[-1], joints[-1], res.x)
    T_star, _ = final_configuration(T[-1], joints[-1], x_star)
    assert np.linalg.norm(T_found[:3, 3] - T_star[:3, 3]) < OPT_TOL_M
    assert np.abs(res.x[6:] - x_star[6:]).max() < OPT_TOL_RAD
    np.testing.assert_array_equal(res.T_object_wrist[-1], T_found)  # the blended trajectory ends there
    assert res.to_meta()["kept"] and res.to_meta()["aperture_deg"] == pytest.approx(
        np.rad2deg(res.x[7]), 1e-3
    )


def test_refine_keeps_the_paper_step_at_an_optimum_and_stays_in_the_trust_region():
    T, joints = _trajectory()
    same = refine_final_grasp(T, joints, _peaked_at(T[-1], joints[-1], np.zeros(8)), FinalGraspConfig())
    assert not same.kept and not same.x.any()
    np.testing.assert_array_equal(same.T_object_wrist, T)
    np.testing.assert_array_equal(same.joints, joints)
    # the optimum 10 cm off along the wrist's x: the search ends on the box's face, no farther
    far = np.zeros(8)
    far[3] = 0.1
    config = FinalGraspConfig(max_nfev=400)

    def ramp(T_c, joints_c):  # increases towards the far optimum everywhere in the box
        return float(np.dot(T_c[:3, 3] - T[-1, :3, 3], T[-1, :3, 0]))

    res = refine_final_grasp(T, joints, ramp, config)
    assert res.kept and np.all(np.abs(res.x) <= config.bounds() + 1e-15)
    assert res.x[3] == pytest.approx(config.bounds()[3], abs=1e-3 * config.bounds()[3])


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"max_position_mm": 0.0}, "trust region"),
        ({"step_aperture_deg": float("nan")}, "trust region"),
        ({"draws": 0}, "draws"),
        ({"blend_steps": 0}, "blend_steps"),
        ({"seed": -1}, "seed"),
    ],
)
def test_invalid_final_grasp_config(kwargs, match):
    with pytest.raises(InputError, match=match):
        FinalGraspConfig(**kwargs)


def test_refine_rejects_mismatched_shapes():
    T, joints = _trajectory()
    with pytest.raises(InputError, match="expected \\(T, 4, 4\\) wrist poses and \\(T, 13\\) joints"):
        refine_final_grasp(T, joints[:-1], lambda T_c, j: 0.0)


# -- the expected quality (pbdgrasp.strategy.ExpectedQuality) and the trajectory it changes ---------------


@pytest.fixture(scope="module")
def ham_world():
    from planning.scene import load_scene
    from planning.world import World

    scene = load_scene("ham")
    with World(scene) as world:
        yield scene, world


def _ham_grasp_in_object(scene):
    from pbdgrasp.bench_fixtures import HAM_GRASP_Q

    q = np.array(HAM_GRASP_Q)
    T_object_wrist = lie.se3_inverse(scene.T_world_object) @ lie.pose_from_q(q)
    return T_object_wrist, q[6:]


def test_expected_quality_of_vanishing_draws_is_the_quality_at_the_configuration(ham_world):
    from pbdgrasp.strategy import ExpectedQuality

    scene, world = ham_world
    T_object_wrist, joints = _ham_grasp_in_object(scene)
    tiny = 1e-18 * np.eye(19)
    score = ExpectedQuality(
        HandCloser(world), scene.T_world_object, 1e-18 * np.eye(6), tiny, 3, np.random.default_rng(0)
    )
    q_world = np.concatenate([lie.q_from_pose(scene.T_world_object @ T_object_wrist), joints])
    direct = HandCloser(world).close(q_world).quality
    assert direct > 0.1  # the hand-placed grasp (epsilon ~0.17)
    np.testing.assert_allclose(score.qualities(T_object_wrist, joints), direct, atol=EPS_NEAR_TOL)
    assert score(T_object_wrist, joints) == pytest.approx(direct, abs=EPS_NEAR_TOL)


def test_expected_quality_draws_follow_the_offset_and_the_covariances(ham_world):
    """The draws' configurations, by another route (the relative pose's log), are centred on the candidate
    moved by the offset and have the covariance asked."""
    from pbdgrasp.strategy import ExpectedQuality

    scene, world = ham_world
    T_object_wrist, joints = _ham_grasp_in_object(scene)
    rng = np.random.default_rng(1)
    A = rng.normal(size=(19, 19)) * np.r_[[0.02] * 3, [0.004] * 3, [0.05] * 13][:, None]
    cov = A @ A.T
    offset = np.r_[0.05, -0.02, 0.01, 0.01, -0.02, 0.03, np.full(13, 0.05)]
    n = 20_000
    tiny = 1e-18 * np.eye(6)
    score = ExpectedQuality(
        HandCloser(world), scene.T_world_object, tiny, cov, n, np.random.default_rng(2), offset
    )
    T_world_wrist, q_joints = score.draws(T_object_wrist, joints)
    T_mean = scene.T_world_object @ T_object_wrist @ lie.se3_exp(offset[:6])
    xi = lie.se3_log(lie.se3_inverse(T_mean) @ T_world_wrist)
    np.testing.assert_allclose(xi, score.dq[:, :6], atol=1e-6)  # the body-frame perturbation (object ~3e-8)
    np.testing.assert_array_equal(q_joints, sah.clip_joints(joints + offset[6:] + score.dq[:, 6:]))
    empirical = np.cov(score.dq, rowvar=False)
    sd = np.sqrt(np.diag(cov))
    assert np.abs((empirical - cov) / np.outer(sd, sd)).max() < 0.05  # correlations within 5e-2 (n = 2e4)


def test_with_final_grasp_recomputes_the_fingertip_errors_and_keeps_sigma_r():
    from retarget.retargeting import retarget_fingertips

    T, joints = _trajectory(n=4)
    targets = sah.fingertip_positions_in(T, joints)
    res = retarget_fingertips(targets, T, np.eye(4), joints0=joints[0])
    x = np.zeros(8)
    x[7] = -0.2  # open the hand: the fingertips leave their targets
    refined = refine_final_grasp(
        res.T_object_wrist, res.joints, lambda T_c, j: -np.sum(j), FinalGraspConfig()
    )
    assert refined.kept and refined.x[7] < 0  # the made-up objective prefers an open hand
    out = res.with_final_grasp(refined)
    err = np.linalg.norm(sah.fingertip_positions_in(out.T_object_wrist, out.joints) - targets, axis=-1)
    np.testing.assert_allclose(out.fingertip_error_mm, 1e3 * err, atol=1e-9)
    assert out.fingertip_rmse_mm[-1] > res.fingertip_rmse_mm[-1] + 5.0
    np.testing.assert_array_equal(out.cov_retarget, res.cov_retarget)
    assert out.meta["final_grasp"]["kept"] and out.meta["final_grasp"]["aperture_deg"] < 0


def test_the_ham_strategy_refined_closes_better_and_ends_where_its_blend_says():
    """The whole path on the ham demonstration, with a small search: the kept final step's draws close to a
    higher mean epsilon than the paper's (a fresh ExpectedQuality, the same seed: the same draws), the
    trajectory ends at it, and the steps before the blend window are the fingertip search's, bit for bit."""
    from pbdgrasp.scene_model import learn_in_scene
    from pbdgrasp.strategy import ExpectedQuality, _trajectory, retarget_in_scene
    from planning.scene import load_scene
    from planning.world import World
    from retarget.demonstration import Demonstration
    from retarget.retargeting import RetargetConfig

    demo, scene = Demonstration.load("ham"), load_scene("ham")
    settings = FinalGraspConfig(draws=12, max_nfev=40, blend_steps=10)
    paper, res_paper = retarget_in_scene(demo, scene, RetargetConfig(final_grasp="paper"))
    traj, res = retarget_in_scene(demo, scene, RetargetConfig(final_grasp_settings=settings))
    info = res.meta["final_grasp"]
    assert res.meta["final_grasp_method"] == "refined" and paper.meta["final_grasp_method"] == "paper"
    assert info["kept"] and info["expected_quality_after"] > info["expected_quality_before"]
    np.testing.assert_array_equal(traj.T_object_wrist[:-10], paper.T_object_wrist[:-10])
    np.testing.assert_array_equal(traj.cov_retarget, paper.cov_retarget)  # Sigma_r of the fingertip search
    x = np.r_[np.deg2rad(info["rotation_deg"]), 1e-3 * np.array(info["position_mm"])]
    x = np.r_[x, np.deg2rad(info["thumb_deg"]), np.deg2rad(info["aperture_deg"])]
    T_end, j_end = final_configuration(paper.T_object_wrist[-1], paper.joints[-1], x)
    np.testing.assert_allclose(traj.T_object_wrist[-1], T_end, atol=1e-6)  # meta rounds to 1e-3 mm, deg
    np.testing.assert_allclose(traj.joints[-1], j_end, atol=1e-4)
    model = learn_in_scene(_trajectory(demo, res_paper, {}), scene)
    offset = np.r_[
        lie.local(paper.T_object_wrist[-1], model.T_object_wrist_mean[-1]),
        model.joints_mean[-1] - paper.joints[-1],
    ]
    with World(scene) as world:
        rng = np.random.default_rng(settings.seed)
        score = ExpectedQuality(
            HandCloser(world), scene.T_world_object, scene.cov_object, model.cov[-1], 12, rng, offset
        )
        before = score(paper.T_object_wrist[-1], paper.joints[-1])
        after = score(traj.T_object_wrist[-1], traj.joints[-1])
    assert before == pytest.approx(info["expected_quality_before"], abs=1e-9)
    assert after == pytest.approx(info["expected_quality_after"], abs=1e-3)
