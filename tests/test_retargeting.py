"""Retargeting: a demonstration the SAH can reproduce exactly is recovered; Sigma_r; d1..d7; the CLI."""

from __future__ import annotations

import numpy as np
import pytest

from assets import sah
from assets import se3 as lie
from assets.errors import InputError
from retarget.retargeting import (
    PAPER_WEIGHTS,
    RetargetConfig,
    fingertip_cov_to_config,
    palm_alignment,
    retarget_fingertips,
    step_costs,
)
from retarget.trajectory import Trajectory

#: Fingertip error of a retargeted trajectory that the SAH can follow exactly [mm].
RECOVERY_TOL_MM = 0.5
#: Same, when a collision constraint moves the wrist off the demonstrated one [mm].
CONSTRAINED_TOL_MM = 1.0
#: Relative tolerance of J Sigma_r J^T against the fingertip covariance.
COV_RTOL = 1e-8


def sah_trajectory(n: int = 12, seed: int = 0):
    """A smooth SAH motion: wrist on an SE(3) line, joints from open towards a random closure."""
    rng = np.random.default_rng(seed)
    s = np.linspace(0.0, 1.0, n)[:, None]
    j0 = sah.rest_joints()
    j1 = j0.copy()
    lo, hi = sah.JOINT_LIMITS[:, 0] + 0.05, sah.JOINT_LIMITS[:, 1] - 0.05
    j1[1:] = np.clip(j0[1:] + np.deg2rad(rng.uniform(5.0, 30.0, 12)), lo[1:], hi[1:])
    for i in (1, 4, 7, 10):  # abductions
        j1[i] = np.deg2rad(rng.uniform(-10.0, 10.0))
    joints = j0 + (j1 - j0) * s  # thumb base stays at the rest pose's 90 deg (IK keeps it)
    xi0 = np.array([0.3, -0.2, 0.1, 0.0, 0.05, -0.25])
    xi1 = np.array([0.2, -0.1, 0.05, 0.0, 0.03, -0.22])
    T_object_wrist = lie.se3_exp(xi0 + (xi1 - xi0) * s)
    return T_object_wrist, joints, sah.fingertip_positions_in(T_object_wrist, joints)


def test_recovers_a_trajectory_the_sah_can_follow():
    T, joints, tips = sah_trajectory()
    res = retarget_fingertips(tips, T, T_hwrist_rwrist=np.eye(4), joints0=joints[0])
    got = sah.fingertip_positions_in(res.T_object_wrist, res.joints)
    err_mm = 1e3 * np.max(np.linalg.norm(got - tips, axis=-1))
    assert err_mm < RECOVERY_TOL_MM, f"max fingertip error {err_mm:.3f} mm"
    assert np.max(res.fingertip_error_mm) < RECOVERY_TOL_MM
    assert res.rmse_mm < RECOVERY_TOL_MM
    assert np.all(res.joints >= sah.JOINT_LIMITS[:, 0] - 1e-12)
    assert np.all(res.joints <= sah.JOINT_LIMITS[:, 1] + 1e-12)
    # With all four fingertips reachable the wrist is redundant: only w5 (0.1 per mm) pulls it to the
    # demonstrated one while d7 (10 per rad of joint change from the previous step) holds it where it
    # was, so the greedy per-step optimum drifts (31 mm measured); it must stay bounded.
    d_wrist_mm = 1e3 * np.max(np.linalg.norm(res.T_object_wrist[:, :3, 3] - T[:, :3, 3], axis=-1))
    assert d_wrist_mm < 50.0, f"wrist {d_wrist_mm:.1f} mm off"
    assert res.q.shape == (len(T), 19)


def test_collision_term_moves_the_wrist_out_of_a_forbidden_region():
    T, joints, tips = sah_trajectory(n=6, seed=1)
    # A wall 4 mm inside the demonstrated wrist positions: the wrist must stay on the x <= x_max side.
    x_max = float(T[:, 0, 3].min()) - 0.004

    def is_free(q):
        assert q.shape == (19,)
        return q[0] <= x_max

    config = RetargetConfig(escape_factors=(4.0, 16.0))
    res = retarget_fingertips(tips, T, np.eye(4), is_free=is_free, joints0=joints[0], config=config)
    assert np.all(res.distances[:, 5] == 0.0), "a step ended in collision"
    assert np.all(res.T_object_wrist[:, 0, 3] <= x_max)
    assert np.max(res.fingertip_error_mm) < CONSTRAINED_TOL_MM, res.fingertip_error_mm.max()
    assert np.all(res.n_collision_checks <= res.nfev * (6 + 4 * config.contact_stop_iterations))
    assert res.meta["steps_in_collision"] == 0


def test_depth_graded_collision_term_leaves_a_plateau_the_0_1_term_cannot():
    T, joints, tips = sah_trajectory(n=6, seed=1)
    # The same wall as above: the first step starts 4 mm or more inside it, without escape restarts.
    x_max = float(T[:, 0, 3].min()) - 0.004

    def is_free(q):
        return q[0] <= x_max

    def penetration(q):
        assert q.shape == (19,)
        return max(0.0, q[0] - x_max)

    plateau = retarget_fingertips(tips, T, np.eye(4), is_free=is_free, joints0=joints[0])
    assert plateau.meta["steps_in_collision"] > 0  # the 0/1 term alone: stuck inside from the start
    res = retarget_fingertips(tips, T, np.eye(4), joints0=joints[0], penetration=penetration)
    assert res.meta["steps_in_collision"] == 0
    assert res.meta["max_penetration_mm"] == 0.0
    assert np.all(res.T_object_wrist[:, 0, 3] <= x_max)
    assert np.max(res.fingertip_error_mm) < CONSTRAINED_TOL_MM, res.fingertip_error_mm.max()


def test_a_finger_stops_at_contact_where_its_target_lies_beyond_a_wall():
    T, joints, tips = sah_trajectory(n=6, seed=3)
    # A wall across the index fingertip's path, 1 mm beyond its target at step 3: the targets of steps
    # 4 and 5 lie `depth_mm` beyond it, the other fingers' targets are unconstrained.
    index = tips[:, 1]
    normal = (index[-1] - index[0]) / np.linalg.norm(index[-1] - index[0])
    wall = float(normal @ index[3]) + 0.001
    depth_mm = 1e3 * (index @ normal - wall)
    assert np.all(depth_mm[:4] < 0.0) and np.all(depth_mm[4:] > 5.0)

    def penetration(q):
        tip = sah.fingertip_positions_in(lie.pose_from_q(q), q[6:])[1]
        return max(0.0, float(normal @ tip) - wall)

    res = retarget_fingertips(tips, T, np.eye(4), joints0=joints[0], penetration=penetration)
    assert res.meta["steps_in_collision"] == 0
    err = res.fingertip_error_mm
    # The index stops on the wall (within the bisection's 1/16 of its step), the others reach their
    # targets: the error is the wall's depth, nowhere else.
    assert np.all(err[4:, 1] >= depth_mm[4:] - 1e-6) and np.all(err[4:, 1] <= depth_mm[4:] + 2.0), err[4:, 1]
    assert np.max(err[:, [0, 2, 3]]) < RECOVERY_TOL_MM, err
    assert np.max(err[:4]) < RECOVERY_TOL_MM
    # Without the stop the IK drives the index onto its target, so the search moves the wrist and every
    # finger misses.
    config = RetargetConfig(contact_stop=False)
    off = retarget_fingertips(tips, T, np.eye(4), joints0=joints[0], penetration=penetration, config=config)
    assert np.max(off.fingertip_error_mm[-1, [0, 2, 3]]) > 2.0


def test_the_first_step_stops_its_fingers_at_contact_moving_from_the_seed():
    """One step whose index target lies 5 mm beyond a wall that the seed's (open) index is clear of: the
    fingers stop at contact moving from the seed (there is no tau_r(t - 1) yet), so the step ends free
    with the index on the wall and the other fingers on their targets."""
    T, joints, tips = sah_trajectory(n=6, seed=3)
    T, tips = T[-1:], tips[-1:]
    seed_joints = sah.rest_joints()
    p_seed = sah.fingertip_positions_in(T[0], seed_joints)[1]
    target = tips[0, 1]
    normal = (target - p_seed) / np.linalg.norm(target - p_seed)
    wall = float(normal @ target) - 0.005
    assert normal @ p_seed < wall - 0.002  # the seed's index is clear of the wall

    def penetration(q):
        tip = sah.fingertip_positions_in(lie.pose_from_q(q), q[6:])[1]
        return max(0.0, float(normal @ tip) - wall)

    res = retarget_fingertips(tips, T, np.eye(4), joints0=seed_joints, penetration=penetration)
    assert res.meta["steps_in_collision"] == 0
    err = res.fingertip_error_mm[0]
    assert 5.0 - 1e-6 <= err[1] <= 5.0 + 2.0, err
    assert np.max(err[[0, 2, 3]]) < CONSTRAINED_TOL_MM, err


def test_a_step_moves_the_wrist_at_most_the_trust_region():
    T, joints, tips = sah_trajectory(n=3, seed=4)
    jumped = tips.copy()
    jumped[2] += [0.3, 0.0, 0.0]  # the last step's targets leap 30 cm
    config = RetargetConfig(max_wrist_step_mm=20.0)
    res = retarget_fingertips(jumped, T, np.eye(4), joints0=joints[0], config=config)
    step_mm = 1e3 * np.linalg.norm(np.diff(res.T_object_wrist[:, :3, 3], axis=0), axis=-1)
    assert step_mm[1] <= 20.0 + 1e-9 and step_mm[1] > 15.0, step_mm  # it goes as far as it may
    R_1, R_2 = res.T_object_wrist[1, :3, :3], res.T_object_wrist[2, :3, :3]
    rot_deg = np.rad2deg(np.linalg.norm(lie.so3_log(R_1.T @ R_2)))
    assert rot_deg <= config.max_wrist_step_deg + 1e-9


def test_sigma_r_is_symmetric_psd_and_maps_back_to_the_fingertip_covariance():
    T, joints, tips = sah_trajectory(n=3, seed=2)
    far = tips.copy()
    far[:, 0] += [0.0, 0.0, 0.2]  # the thumb target is out of reach: a non-zero error
    res = retarget_fingertips(far, T, np.eye(4), joints0=joints[0], config=RetargetConfig(max_nfev=80))
    C = res.cov_retarget
    assert C.shape == (3, 19, 19)
    assert np.all(res.fingertip_rmse_mm > 1.0)
    np.testing.assert_allclose(C, np.swapaxes(C, -1, -2), rtol=0, atol=1e-15)
    eig = np.linalg.eigvalsh(C)
    assert eig.min() > -1e-12 * eig.max()
    assert np.all(np.sum(eig > 1e-9 * eig.max(axis=-1, keepdims=True), axis=-1) <= 12)  # degenerate
    # J Sigma_r J^T is the isotropic fingertip covariance mse / 3 * I_12 (J has full row rank 12).
    mse = (res.fingertip_rmse_mm * 1e-3) ** 2
    J = sah.fingertip_jacobian(res.T_object_wrist, res.joints)
    back = J @ C @ np.swapaxes(J, -1, -2)
    expected = (mse / 3)[:, None, None] * np.eye(12)
    assert np.max(np.abs(back - expected)) < COV_RTOL * mse.max()
    direct = fingertip_cov_to_config(res.T_object_wrist, res.joints, mse)
    np.testing.assert_allclose(direct, C, rtol=1e-13, atol=1e-12 * mse.max())
    assert res.meta["covariance_map"] == "configuration" and np.abs(C[:, :6, :6]).max() > 0.0  # the wrist too
    held = RetargetConfig(max_nfev=80, covariance_map="finger_joints")
    res_f = retarget_fingertips(far, T, np.eye(4), joints0=joints[0], config=held)
    back_f = J @ res_f.cov_retarget @ np.swapaxes(J, -1, -2)
    assert np.max(np.abs(back_f - expected)) < COV_RTOL * mse.max()  # the same fingertip covariance
    assert not res_f.cov_retarget[:, :6].any() and res_f.meta["covariance_map"] == "finger_joints"


def test_step_costs_by_hand():
    joints = sah.rest_joints()
    T = lie.make_pose(lie.so3_exp([0.0, 0.0, np.deg2rad(5.0)]), [0.01, 0.0, 0.0])
    tips = sah.fingertip_positions_in(T, joints)
    targets = tips + np.array([[0.002, 0, 0], [0, 0.001, 0], [0, 0, 0], [0, 0, 0.003]])
    prev = joints.copy()
    prev[5] += np.deg2rad(2.0)
    deg = RetargetConfig(smoothness_unit="deg")
    c = step_costs(T, joints, targets, np.eye(4), prev, collision_free=False, config=deg)
    np.testing.assert_allclose(c.d, [2.0, 1.0, 0.0, 3.0, 10.0 + 5.0, 1.0, 2.0], atol=1e-9)
    assert c.total == pytest.approx(3 * 2 + 1 + 0 + 3 + 0.1 * 15 + 10000 + 10 * 2)
    rad = step_costs(T, joints, targets, np.eye(4), None, collision_free=True, config=RetargetConfig())
    assert rad.d[5] == 0.0 and rad.d[6] == 0.0  # first step: no smoothness term


def test_palm_alignment_keeps_the_axes():
    T = palm_alignment()
    np.testing.assert_allclose(T[:3, :3], np.eye(3))
    assert -0.08 < T[2, 3] < 0.0  # the larger SAH palm sits further back along the fingers


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"weights": (1, 2, 3)}, "weights"),
        ({"smoothness_unit": "grad"}, "smoothness_unit"),
        ({"max_nfev": 0}, "max_nfev"),
        ({"penetration_weight_per_mm": -1.0}, "penetration_weight_per_mm"),
        ({"thumb_base_seed_deg": float("nan")}, "thumb_base_seed_deg"),
        ({"contact_stop_iterations": 0}, "contact_stop_iterations"),
        ({"max_wrist_step_mm": 0.0}, "max_wrist_step_mm"),
        ({"max_wrist_step_deg": float("inf")}, "max_wrist_step_mm and _deg"),
        ({"targets": "contacts"}, "targets"),
        ({"scaled_wrist_weight": -1.0}, "scaled_wrist_weight"),
        ({"scaled_wrist_weight": float("nan")}, "scaled_wrist_weight"),
        ({"scaled_wrist_weight": "by_object"}, "scaled_wrist_weight"),
        ({"scaled_wrist_weight": True}, "scaled_wrist_weight"),
        ({"covariance_map": "wrist"}, "covariance_map: expected one of configuration, finger_joints"),
        ({"final_grasp": "best"}, "final_grasp: expected one of by_grasp_type, paper, refined"),
        ({"final_grasp_settings": {"draws": 8}}, "final_grasp_settings: expected a FinalGraspConfig"),
    ],
)
def test_invalid_config(kwargs, match):
    with pytest.raises(InputError, match=match):
        RetargetConfig(**kwargs)


def test_scaled_targets_take_their_own_wrist_weight_and_fingertip_targets_the_papers():
    by_strategy = RetargetConfig()  # salt's w5 is 3, every other strategy's the paper's
    assert by_strategy.weights_for("scaled", "salt") == (3.0, 1.0, 1.0, 1.0, 3.0, 10000.0, 10.0)
    assert by_strategy.weights_for("scaled", "chips") == PAPER_WEIGHTS
    assert by_strategy.weights_for("fingertips", "salt") == PAPER_WEIGHTS
    assert RetargetConfig(scaled_wrist_weight=None).weights_for("scaled", "salt") == PAPER_WEIGHTS
    heavy = RetargetConfig(scaled_wrist_weight=2.5)
    assert heavy.weights_for("scaled", "chips")[4] == 2.5
    assert heavy.weights_for("fingertips", "chips") == PAPER_WEIGHTS


def test_hand_scale_is_the_ratio_of_the_straight_hands_palm_to_tip_distances():
    from assets import human_hand
    from retarget.objective import hand_scale, palm_centre, scaled_targets
    from retarget.virtual_fingers import virtual_fingers_of

    vf = virtual_fingers_of(np.zeros(20), n_virtual=3, adjacent_only=True)
    s = hand_scale(vf)
    # by hand: the SAH's middle finger, straight, against the human finger it follows
    i = sah.FINGERS.index("middle")
    human = human_hand.fk(np.zeros(20))[human_hand.TIP_LINKS[vf.human_indices[i]]][:3, 3]
    sah_tip = sah.fingertip_positions(np.zeros(13))[i]
    expected = np.linalg.norm(sah_tip - palm_centre(sah)) / np.linalg.norm(human - palm_centre(human_hand))
    assert s[i] == pytest.approx(expected, rel=1e-12)
    assert 1.2 < s[1:].min() and s[1:].max() < 1.6 and 1.8 < s[0] < 2.4  # dex-retargeting's 1.2-1.6
    # the scaled targets lie on the rays from the human palm centre, s times as far
    rng = np.random.default_rng(0)
    T = np.stack([lie.se3_exp(rng.normal(size=6) * 0.3) for _ in range(3)])
    tv = rng.normal(size=(3, 4, 3)) * 0.1
    palm = T[:, :3, :3] @ palm_centre(human_hand) + T[:, :3, 3]
    out = scaled_targets(tv, T, s)
    np.testing.assert_allclose(out - palm[:, None], s[None, :, None] * (tv - palm[:, None]), atol=1e-15)
    np.testing.assert_allclose(scaled_targets(tv, T, np.ones(4)), tv, atol=1e-15)


def test_invalid_targets():
    with pytest.raises(InputError, match="expected targets"):
        retarget_fingertips(np.zeros((3, 5, 3)), np.tile(np.eye(4), (3, 1, 1)), np.eye(4))
    with pytest.raises(InputError, match="finite"):
        retarget_fingertips(np.full((2, 4, 3), np.nan), np.tile(np.eye(4), (2, 1, 1)), np.eye(4))


# --- the CLI -----------------------------------------------------------------------------------------


def _tiny_demo(path):
    """A 3-step demonstration of the ham can with the open human hand well above the object."""
    from retarget.demonstration import Demonstration, default_object_prior

    n = 3
    T = np.tile(lie.make_pose(lie.so3_exp([np.pi, 0.0, 0.0]), [0.0, 0.0, 0.45]), (n, 1, 1))
    T[:, 2, 3] -= 0.01 * np.arange(n)
    mu, cov = default_object_prior()
    demo = Demonstration(
        T_object_wrist=T,
        joints=np.zeros((n, 20)),
        t_s=np.arange(n) / 20.0,
        object="ham",
        grasp_type="precision",
        T_world_object_mean=mu,
        cov_object=cov,
    )
    demo.save(path)
    return demo


def test_cli_writes_a_valid_trajectory_atomically(tmp_path, capsys):
    from pbdgrasp.cli import main

    _tiny_demo(tmp_path / "tiny.npz")
    out = tmp_path / "out" / "tiny.traj.npz"
    out.parent.mkdir()  # the output policy refuses a missing parent (tests/test_output_policy.py)
    args = ["retarget", str(tmp_path / "tiny.npz"), "-o", str(out), "--max-nfev", "40", "--no-progress"]
    status = main([*args, "--final-grasp", "paper"])
    assert status == 0
    traj = Trajectory.load(out)
    assert traj.num_steps == 3 and traj.object == "ham" and traj.grasp_type == "precision"
    assert traj.dt_s == pytest.approx(0.05)
    assert "virtual_fingers" in traj.meta and traj.meta["seed"] == 0
    assert traj.meta["targets"] == "fingertips" and traj.meta["hand_scale"] == [1.0] * 4  # a precision grasp
    assert "final_grasp" not in traj.meta and traj.meta["final_grasp_method"] == "paper"
    assert traj.meta["covariance_map"] == "configuration"
    shape = traj.meta["last_step"]  # the open hand 45 cm above the can: nothing touches
    assert shape["contact_links"] == 0 and shape["palm_to_object_mm"] > 100
    assert sorted(p.name for p in out.parent.iterdir()) == ["tiny.traj.npz"]  # no temporary left behind
    line = capsys.readouterr().out.strip()
    assert "fingertip RMSE" in line and "steps in collision 0" in line


def test_cli_learn_is_retarget_then_infer(tmp_path, capsys):
    """``learn`` gives bit for bit the trajectory and the model of ``retarget`` then ``infer --scene``."""
    from pbdgrasp.cli import main

    _tiny_demo(tmp_path / "tiny.npz")
    nfev = ["--max-nfev", "40", "--no-progress", "--final-grasp", "paper"]
    assert main(["retarget", str(tmp_path / "tiny.npz"), "-o", str(tmp_path / "a.traj.npz"), *nfev]) == 0
    infer = ["infer", str(tmp_path / "a.traj.npz"), "--scene", "ham", "-o", str(tmp_path / "a.model.npz")]
    assert main([*infer, "--no-progress"]) == 0
    learn = ["learn", str(tmp_path / "tiny.npz"), "-o", str(tmp_path / "b.model.npz")]
    assert main([*learn, "--trajectory", str(tmp_path / "b.traj.npz"), *nfev]) == 0
    for kind in ("traj", "model"):
        a, b = np.load(tmp_path / f"a.{kind}.npz"), np.load(tmp_path / f"b.{kind}.npz")
        for key in a.files:
            if a[key].dtype.kind in "fiub" and key not in ("solve_time_s", "traj_solve_time_s"):
                assert np.array_equal(a[key], b[key]), (kind, key)
    assert "constrained steps" in capsys.readouterr().out


def test_cli_errors_cleanly_on_a_bad_demonstration(tmp_path, capsys):
    from pbdgrasp.cli import main

    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not an archive")
    out = tmp_path / "x.traj.npz"
    assert main(["retarget", str(bad), "-o", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: ") and "bad.npz" in err[0]
    assert not out.exists()
    assert main(["retarget", "no_such_demo", "-o", str(out)]) == 2
    assert "unknown demonstration" in capsys.readouterr().err
    assert main(["retarget", str(bad), "-o", str(tmp_path / "x.npz")]) == 2
    assert ".traj.npz" in capsys.readouterr().err


_PALM_LINKS = (
    "wrist",
    "thumb_module",
    "index_proximal",
    "middle_proximal",
    "ring_proximal",
    "thumb_proximal",
)


def _last_step_distances(name, targets):
    """Per SAH link, the signed distance [m] to the object at tau_r's last step of a whole demonstration."""
    from pbdgrasp.strategy import _world_q, retarget_in_scene
    from planning.scene import load_scene
    from planning.world import World
    from retarget.demonstration import Demonstration

    scene = load_scene(name)
    _, res = retarget_in_scene(Demonstration.load(name), scene, RetargetConfig(targets=targets))
    with World(scene) as world:
        d = world.link_signed_distances(
            _world_q(scene.T_world_object, res.q[-1]), 0.2, bodies=(world.object_id,)
        )
        return dict(zip((world.base_name, *world.link_names), d, strict=True)), res


@pytest.mark.parametrize("name", ["chips", "salt"])
def test_a_power_strategy_touches_its_object_with_the_palm_or_the_proximal_links(name):
    from pbdgrasp.strategy import TOUCH_M

    d, res = _last_step_distances(name, "by_grasp_type")
    assert res.meta["targets"] == "scaled"
    assert res.meta["weights"][4] == (3.0 if name == "salt" else 0.1)  # the trajectory records its w5
    assert min(d[link] for link in _PALM_LINKS) <= TOUCH_M, {k: round(1e3 * v, 1) for k, v in d.items()}
    assert res.meta["last_step"]["palm_to_object_mm"] < 15.0  # a wrap (the paper's targets: 30+ mm)
    if name == "chips":  # the paper's targets: the palm stands back, only fingertips and distals near
        d_paper, _ = _last_step_distances(name, "fingertips")
        assert d_paper["wrist"] > 0.03


def test_a_heavier_scaled_wrist_weight_keeps_the_palm_at_the_human_palms_place():
    """Salt's last 12 steps: with the paper's w5 the thumb's scaled target pulls the SAH palm centre 55 mm
    from the human's (the palm 12 mm off the box); with w5 = 3, 19 mm (5 mm off the box)."""
    from assets import human_hand
    from pbdgrasp.strategy import retarget_in_scene
    from planning.scene import load_scene
    from retarget.demonstration import Demonstration
    from retarget.objective import palm_centre

    demo = Demonstration.load("salt")
    tail = demo.last_steps(12)
    T_h = demo.T_object_wrist[-1]
    p_h = T_h[:3, :3] @ palm_centre(human_hand) + T_h[:3, 3]
    gap, to_object = {}, {}
    for w5 in (None, 3.0):
        _, res = retarget_in_scene(tail, load_scene("salt"), RetargetConfig(scaled_wrist_weight=w5))
        assert res.meta["weights"][4] == (0.1 if w5 is None else w5)
        T_r = res.T_object_wrist[-1]
        gap[w5] = np.linalg.norm(T_r[:3, :3] @ palm_centre(sah) + T_r[:3, 3] - p_h)
        to_object[w5] = res.meta["last_step"]["palm_to_object_mm"]
    assert gap[3.0] < 0.03 and gap[3.0] < gap[None] - 0.02, gap
    assert to_object[3.0] < to_object[None], to_object
