"""The grasp-quality ceiling (pbdgrasp.ceiling): its surface and pose sampling against closed forms, its
refinement and perturbation against a hand-placed grasp scored independently, the ceiling near a strategy
(its draws counted again in pybullet, its trust region against its bounds), and its command line."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from assets import sah
from assets.errors import InputError
from assets.se3 import make_pose, pose_from_q, q_from_pose, so3_exp
from inference.sampler import sample
from pbdgrasp import ceiling, ceiling_poses
from pbdgrasp.bench_fixtures import HAM_GRASP_Q
from pbdgrasp.cli import main
from planning.autograsp import AutoGraspConfig, HandCloser
from planning.scene import load_scene
from planning.world import World
from retarget.objective import palm_centre

# a unit cube centred at the origin, outward (right-handed) triangles
_CUBE_V = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
_CUBE_T = np.array(
    [[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
     [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]]
)  # fmt: skip


def test_surface_samples_lie_on_a_cube_with_outward_normals_and_equal_faces():
    rng = np.random.default_rng(0)
    p, n = ceiling_poses.surface_samples(_CUBE_V, _CUBE_T, 60_000, rng)
    face = np.argmax(np.abs(p), axis=1) + 3 * (p[np.arange(len(p)), np.argmax(np.abs(p), axis=1)] > 0)
    np.testing.assert_allclose(np.max(np.abs(p), axis=1), 0.5, atol=1e-12)  # on the surface
    np.testing.assert_allclose(np.linalg.norm(n, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(np.sum(n * p, axis=1), 0.5, atol=1e-12)  # outward: n . p = half the side
    counts = np.bincount(face, minlength=6)
    assert np.all(np.abs(counts - 10_000) < 5 * np.sqrt(10_000 * 5 / 6))  # area-uniform, 5 sigma


def test_wrist_poses_face_the_point_at_the_standoff_along_the_hand_axis():
    rng = np.random.default_rng(1)
    p, n = ceiling_poses.surface_samples(_CUBE_V, _CUBE_T, 500, rng)
    cfg = ceiling.CeilingConfig(standoff_m=(0.02, 0.02), cone_deg=0.0, reach_beyond_knuckles_m=0.03)
    T = ceiling_poses.wrist_poses(p, n, cfg, rng)
    R = T[:, :3, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.tile(np.eye(3), (500, 1, 1)), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(R[:, :, 0], -n, atol=1e-12)  # the palm (+x) faces the surface
    # the grasp centre p + s n, in the wrist frame, lies on the hand's axis from the palm centre on
    centre = p + 0.02 * n
    local = np.einsum("nji,nj->ni", R, centre - T[:, :3, 3])
    palm = palm_centre(sah)
    axis = palm / np.linalg.norm(palm)  # the knuckles are twice the palm centre: the axis goes through 0
    s = (local - palm) @ axis
    np.testing.assert_allclose(local - palm, s[:, None] * axis, atol=1e-12)
    assert s.min() >= -1e-12 and s.max() <= np.linalg.norm(palm) + 0.03 + 1e-12
    # with a cone, the palm's normal stays within it of -n
    wide = ceiling_poses.wrist_poses(p, n, ceiling.CeilingConfig(cone_deg=30.0), rng)
    cos = np.sum(wide[:, :3, 0] * -n, axis=1)
    assert cos.min() >= np.cos(np.deg2rad(30.0)) - 1e-12 and cos.max() > np.cos(np.deg2rad(2.0))


@pytest.fixture(scope="module")
def ham_scorer():
    score = ceiling._Scorer(load_scene("ham"))
    yield score
    score.world.close()


def test_refinement_never_loses_quality_and_its_pose_scores_so_in_a_second_world(ham_scorer):
    """From the hand-placed ham grasp (epsilon ~0.17): the refined pose closes at least as well, and a
    second, independent world and closer give it the same epsilon."""
    q0 = np.array(HAM_GRASP_Q)
    free, e0 = ham_scorer(q0)
    assert free and e0 > 0.1
    cfg = ceiling.CeilingConfig(refine_iterations=15)
    e, q = ceiling._refine(ham_scorer, e0, q0, cfg, np.random.default_rng(2))
    assert e >= e0
    with World(load_scene("ham")) as world:
        again = HandCloser(world, AutoGraspConfig()).close(q)
    assert not again.in_collision and again.quality == pytest.approx(e, abs=1e-12)


def test_a_perturbation_of_zero_gives_the_pose_itself_every_time(ham_scorer):
    q0 = np.array(HAM_GRASP_Q)
    e0 = ham_scorer(q0)[1]
    still = ceiling.CeilingConfig(perturb_m=0.0, perturb_deg=0.0, perturb_draws=3)
    mean, valid = ceiling._shake(ham_scorer, q0, still, np.random.default_rng(3))
    assert mean == pytest.approx(e0, abs=1e-9) and valid == 1.0


def test_chunks_on_two_dask_workers_give_the_one_process_result():
    """The serial run is the reference: the same seed on two worker processes, in uneven chunks, gives the
    same counts, valid qualities, refined poses and robustness, in the same order."""
    scene = load_scene("chips")
    settings = dict(samples=2_400, refine_best=2, refine_iterations=5, perturb_draws=4)
    one = ceiling.grasp_ceiling(scene, ceiling.CeilingConfig(**settings), np.random.default_rng(3))
    two = ceiling.grasp_ceiling(
        scene, ceiling.CeilingConfig(**settings, workers=2, chunk=700), np.random.default_rng(3)
    )
    assert one.valid > 0  # the comparison covers the valid list's order and the refinement
    assert dataclasses.replace(two, seconds=0.0) == dataclasses.replace(one, seconds=0.0)


@pytest.mark.parametrize(
    "bad",
    [
        {"samples": 0},
        {"standoff_m": (0.05, 0.01)},
        {"cone_deg": 120.0},
        {"epsilon": 0.0},
        {"perturb_m": -1},
        {"workers": 0},
        {"chunk": 0},
    ],
)
def test_bad_settings_are_refused(bad):
    with pytest.raises(InputError, match="ceiling"):
        ceiling.CeilingConfig(**bad)


def test_cli_writes_the_most_robust_pose_that_quality_scores_alike(tmp_path, capsys):
    """Chips, 1500 poses, seed 0 (a few valid): the written Q.json, closed again by ``pbdgrasp quality``,
    has the refined epsilon the JSON reports for it."""
    best = tmp_path / "best.json"
    argv = ["ceiling", "--scene", "chips", "--samples", "1500", "--refine", "1", "--refine-iterations", "100"]
    argv += ["--json", "-o", str(best)]
    assert main(argv) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["tried"] == 1500 and 0 < out["valid"] <= out["free"] <= 1500
    assert len(out["refined"]) == 1 and out["refined"][0] >= out["valid_quantiles"][2]
    assert main(["quality", "--scene", "chips", "--q", str(best), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)
    assert again["epsilon"] == pytest.approx(out["refined"][0], abs=1e-4)


def test_cli_refuses_a_bad_sample_count_and_warns_when_nothing_is_valid(tmp_path, capsys):
    assert main(["ceiling", "--scene", "ham", "--samples", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--samples" in err[0]
    best = tmp_path / "best.json"
    assert main(["ceiling", "--scene", "ham", "--samples", "50", "-o", str(best)]) == 0
    assert "wrote nothing" in capsys.readouterr().err and not best.exists()


def _turned(T: np.ndarray, axis, angle_deg: float, offset_m=(0.0, 0.0, 0.0)) -> np.ndarray:
    """``T`` moved by ``offset_m`` along its own axes and turned by ``angle_deg`` about its own ``axis``."""
    axis = np.asarray(axis, dtype=float) / np.linalg.norm(axis)
    return T @ make_pose(so3_exp(np.deg2rad(angle_deg) * axis), np.asarray(offset_m, dtype=float))


def test_a_region_holds_what_lies_within_its_bounds_along_the_centres_own_axes():
    """Centre turned 70 deg about a slanted axis: 24 mm along its own y is in and 26 mm out (along the world's
    y, 26 mm is in: the bound is per axis of the centre's frame); an 11 deg turn is in, 13 deg out."""
    centre = make_pose(
        so3_exp(np.deg2rad(70.0) * np.array([1.0, 2.0, 2.0]) / 3.0), np.array([0.1, -0.2, 0.3])
    )
    region = ceiling_poses.Region(centre, 0.025, np.deg2rad(12.0))
    joints = sah.rest_joints()

    def q(T):
        return np.r_[q_from_pose(T), joints]

    assert region.contains(q(centre))
    assert region.contains(q(_turned(centre, [0, 0, 1], 0.0, (0.0, 0.024, 0.0))))
    assert not region.contains(q(_turned(centre, [0, 0, 1], 0.0, (0.0, 0.026, 0.0))))
    world_y = centre.copy()
    world_y[1, 3] += 0.026  # 26 mm along the world's y is within 25 mm along each of the centre's axes
    assert np.all(np.abs(centre[:3, :3].T @ [0.0, 0.026, 0.0]) <= 0.025) and region.contains(q(world_y))
    assert region.contains(q(_turned(centre, [1, -1, 0], 11.0)))
    assert not region.contains(q(_turned(centre, [1, -1, 0], 13.0)))


def test_the_refinement_climbs_to_the_regions_rim_and_not_beyond():
    """A score that grows with the wrist's world x (every pose free): without a region the climb leaves a
    5 mm box; with it, it ends inside the box, higher than it started, within a few steps of the rim."""
    q0 = np.r_[q_from_pose(make_pose(so3_exp(np.array([0.3, -0.2, 0.1])), np.zeros(3))), sah.rest_joints()]
    region = ceiling_poses.Region(pose_from_q(q0), 0.005, np.deg2rad(180.0))

    def score(q):
        return True, float(q[0])

    cfg = ceiling.CeilingConfig(refine_iterations=400, refine_step_m=0.001)
    free_e, free_q = ceiling._refine(score, 0.0, q0, cfg, np.random.default_rng(4))
    assert not region.contains(free_q)
    e, q = ceiling._refine(score, 0.0, q0, cfg, np.random.default_rng(4), region)
    # the largest world x in the box: 5 mm times the L1 norm of the world x axis in the centre's frame
    rim = 0.005 * np.abs(pose_from_q(q0)[0, :3]).sum()
    assert region.contains(q) and 0.0 < e <= rim + 1e-12 and e > rim - 0.003


def test_near_a_strategy_the_draws_are_its_last_marginal_counted_alike_in_pybullet(ham_top_down_model):
    """The ham strategy built in code, 150 draws: the free count is the one of the same draws (the same
    seed through the sampler) checked one by one in a second world; the refined pose stays in the region."""
    scene = load_scene("ham")
    model = ham_top_down_model(12)
    cfg = ceiling.CeilingConfig(samples=150, refine_best=1, refine_iterations=20, perturb_draws=3)
    result = ceiling.grasp_ceiling(scene, cfg, np.random.default_rng(8), near=model)
    in_scene = dataclasses.replace(
        model, T_world_object_mean=scene.T_world_object, cov_object=scene.cov_object
    )
    draws = sample(
        in_scene, model.num_steps - 1, 150, np.random.default_rng(8), joint_limits=sah.JOINT_LIMITS
    )
    with World(scene) as world:
        free = sum(world.is_free(q) for q in draws)
    assert result.tried == 150 and result.free == free and result.valid > 0
    assert result.near.startswith("the ham strategy") and result.region == (25.0, 12.0)
    region = ceiling_poses.Region(scene.T_world_object @ model.T_object_wrist_mean[-1], 0.025, np.deg2rad(12))
    assert len(result.refined) == 1 and region.contains(np.array(result.refined_q[0]))
    assert result.refined[0] >= result.valid_quantiles[2]


def test_cli_near_needs_a_model_and_refuses_a_missing_one(tmp_path, capsys):
    assert main(["ceiling", "--scene", "ham", "--near-position-mm", "5"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--near" in err[0]
    assert main(["ceiling", "--scene", "ham", "--near", str(tmp_path / "none.model.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:")
