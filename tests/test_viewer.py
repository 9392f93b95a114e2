"""The 3-D viewer: its meshes against closed forms, the fingertip marginals against Monte Carlo, the scene
tree the server holds (through viser's API), and screenshots in a real headless Chromium.

The ham strategy is the one built in code (``ham_top_down_model``); the trial is a hand-made descent to the
hand-placed ham grasp (``HAM_GRASP_Q``), so the closed grasp has contacts.
"""

from __future__ import annotations

import json
import os
import shutil

import numpy as np
import pytest

from assets import sah
from assets.errors import InputError
from assets.se3 import pose_from_q, q_from_pose
from assets.sphere_cover import CollisionShape
from inference.model import VariationModel
from pbdgrasp.bench_fixtures import HAM_GRASP_Q
from pbdgrasp.results_db import TrialRecord
from pbdgrasp.viewer import LAYERS
from pbdgrasp.viewer.meshes import (
    ellipsoid_scale_wxyz,
    hand_link_meshes,
    hand_link_poses,
    scene_meshes,
    shape_mesh,
)
from planning.scene import load_scene
from planning.world import World

NEEDS_BROWSER = pytest.mark.skipif(
    shutil.which("chromium") is None and not os.environ.get("CI"),
    reason="no chromium (make test installs Debian's package; under CI=true its absence fails)",
)


# -- meshes ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "shape, volume",
    [
        (CollisionShape("l", "box", (0.03, 0.1, 0.13), np.eye(4)), 0.03 * 0.1 * 0.13),
        (CollisionShape("l", "sphere", (0.012,), np.eye(4)), 4 / 3 * np.pi * 0.012**3),
        (
            CollisionShape("l", "capsule", (0.011, 0.0678), np.eye(4)),
            np.pi * 0.011**2 * (0.0678 + 4 / 3 * 0.011),
        ),
        (CollisionShape("l", "cylinder", (0.02, 0.05), np.eye(4)), np.pi * 0.02**2 * 0.05),
    ],
)
def test_a_primitive_mesh_has_its_closed_form_volume_and_extent(shape, volume):
    mesh = shape_mesh(shape)
    assert mesh.is_watertight
    assert 0.97 * volume < mesh.volume <= volume * (1 + 1e-12)  # tessellation: inscribed polygons
    half_z = {"box": 0.065, "sphere": 0.012, "capsule": 0.0339 + 0.011, "cylinder": 0.025}[shape.type]
    assert mesh.bounds[1, 2] == pytest.approx(half_z, abs=1e-9)


def test_a_shape_is_placed_at_its_urdf_origin():
    T = pose_from_q(np.array([0.01, 0.02, 0.03, 0.0, np.pi / 2, 0.0]))
    mesh = shape_mesh(CollisionShape("l", "capsule", (0.01, 0.04), T))
    assert mesh.centroid == pytest.approx(T[:3, 3], abs=1e-6)
    extent = mesh.bounds[1] - mesh.bounds[0]
    assert extent[0] == pytest.approx(0.06, abs=1e-6) and extent[2] == pytest.approx(0.02, abs=5e-4)


def test_the_hand_meshes_sit_where_pybullet_puts_the_links():
    """At a grasp, each link mesh's bounding box centre (our FK) against pybullet's visual AABB of that link
    (Bullet's own kinematics): within 1 mm."""
    from planning._pybullet import pb

    meshes = hand_link_meshes("sah")
    assert len(meshes) == 18  # 22 links, the 4 tip frames have no geometry
    poses = hand_link_poses(np.asarray(HAM_GRASP_Q))
    with World("ham") as world:
        world.set_q(np.asarray(HAM_GRASP_Q))
        for link, mesh in meshes.items():
            if not any(s.link == link for s in _collision_links()):
                continue  # knuckle spheres: visual only, no AABB in pybullet's collision world
            box = pb.getAABB(world.hand_id, world.link_index(link), physicsClientId=world.client)
            lo, hi = (np.array(v) for v in box)
            ours = mesh.copy().apply_transform(poses[link]).bounds
            # the centres only: Bullet's box of a rotated capsule is the rotated box of its local box
            assert ((lo + hi) / 2) == pytest.approx((ours[0] + ours[1]) / 2, abs=1e-3), link


def _collision_links():
    import assets
    from assets.sphere_cover import collision_shapes

    return collision_shapes(assets.hand_urdf("sah"))


def test_scene_meshes_are_the_scene_table_object_and_obstacles():
    scene = load_scene("jam_hole")
    parts = {p.name: p for p in scene_meshes(scene)}
    assert [p.kind for p in parts.values()] == ["table", "object", *["obstacle"] * len(scene.obstacles)]
    table = parts["table"].mesh.copy().apply_transform(parts["table"].T_world_mesh)
    assert table.bounds[1, 2] == pytest.approx(0.0, abs=1e-12)  # the table top is z = 0
    jar = parts["jam"].mesh.copy().apply_transform(parts["jam"].T_world_mesh)
    assert jar.bounds[0, 2] == pytest.approx(scene.T_world_object[2, 3], abs=1e-6)
    with World(scene) as world:  # the object mesh's extent is pybullet's within its collision margin
        from planning._pybullet import pb

        lo, hi = (np.array(v) for v in pb.getAABB(world.object_id, -1, physicsClientId=world.client))
    assert jar.bounds[0] == pytest.approx(lo, abs=6e-3) and jar.bounds[1] == pytest.approx(hi, abs=6e-3)


def test_an_ellipsoid_rebuilds_its_covariance_with_a_proper_rotation():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(0)
    A = rng.normal(size=(50, 3, 3)) * 1e-2
    cov = A @ np.swapaxes(A, -1, -2)
    scale, wxyz = ellipsoid_scale_wxyz(cov, n_sigma=2.0)
    R = Rotation.from_quat(wxyz[:, [1, 2, 3, 0]]).as_matrix()
    rebuilt = R @ (np.eye(3) * (scale[:, None, :] / 2.0) ** 2) @ np.swapaxes(R, -1, -2)
    assert rebuilt == pytest.approx(cov, abs=1e-12)
    assert np.linalg.det(R) == pytest.approx(np.ones(50))


def test_fingertip_marginals_match_monte_carlo_draws(ham_top_down_model):
    """The linearized J cov J^T against the covariance of the fingertips of 40,000 draws through the exact
    kinematics, for a model with its covariance scaled small (where linearization is exact to first order)."""
    from inference.sampler import sample_marginal

    model = ham_top_down_model(6)
    k = model.num_steps - 1
    mean, cov = sah.fingertip_marginals(model.T_object_wrist_mean, model.joints_mean, model.cov)
    assert mean.shape == (6, 4, 3) and cov.shape == (6, 4, 3, 3)
    small = VariationModel(
        model.T_object_wrist_mean, model.joints_mean, model.cov * 0.01, model.T_world_object_mean,
        model.cov_object, model.params, 1, model.grasp_type, model.object,
    )  # fmt: skip
    T, joints = sample_marginal(small, k, 40_000, np.random.default_rng(1))
    tips = sah.fingertip_positions_in(T, joints)
    for i in range(4):
        mc = np.cov(tips[:, i].T)
        assert 0.01 * cov[k, i] == pytest.approx(mc, rel=0.08, abs=0.05 * np.abs(mc).max())
        assert tips[:, i].mean(axis=0) == pytest.approx(mean[k, i], abs=2e-4)


# -- the server's scene tree -----------------------------------------------------------------------------
def _trial(path: np.ndarray) -> TrialRecord:
    grasp = {"q": path[-1].tolist(), "path": path.tolist(), "closed_q": path[-1].tolist()}
    return TrialRecord("ham", "learned", 3, 0, True, 1.0, 10, 0.17, 0, 1, "ok", "x", "{}", json.dumps(grasp))


def _descent() -> np.ndarray:
    q = np.repeat(np.asarray(HAM_GRASP_Q)[None], 4, axis=0)
    q[:, 2] += np.linspace(0.15, 0.0, 4)
    q[:-1, 6:] = sah.rest_joints()
    return q


@pytest.fixture(scope="module")
def viewer(ham_top_down_model):
    from pbdgrasp.viewer.app import StrategyViewer

    v = StrategyViewer(
        load_scene("ham"),
        {"ham": ham_top_down_model(8)},
        _trial(_descent()),
        np.random.default_rng(0),
        port=0,
    )
    yield v
    v.close()


def _node(v, name):
    return v.server.scene.get_handle_by_name(name)


def test_the_scene_tree_holds_the_scene_the_hand_and_four_ellipsoids_a_step(viewer):
    for name in ("/scene/table", "/scene/ham", *(f"/{layer}" for layer in LAYERS)):
        assert _node(viewer, name) is not None, name
    for link in hand_link_meshes("sah"):
        for root in ("/hand", "/path/hand", "/grasp/hand"):
            assert _node(viewer, f"{root}/{link}") is not None, (root, link)
    for k in range(8):
        assert [_node(viewer, f"/marginals/ham/t{k}/{f}") is not None for f in sah.FINGERS] == [True] * 4
    assert _node(viewer, "/marginals/ham/t8/thumb") is None
    assert _node(viewer, "/marginals/ham/paths") is not None and _node(viewer, "/path/wrist_path") is not None


def test_a_step_puts_the_hand_at_the_mean_and_shows_that_steps_ellipsoids(viewer, ham_top_down_model):
    model = viewer.models["ham"]
    viewer.show_step("ham", 2)
    visible = [[_node(viewer, f"/marginals/ham/t{k}/{f}").visible for f in sah.FINGERS] for k in range(8)]
    assert visible == [[k == 2] * 4 for k in range(8)]
    T_world_wrist = viewer.scene.T_world_object @ model.T_object_wrist_mean[2]
    tips = sah.fingertip_positions_in(T_world_wrist, model.joints_mean[2])
    poses = hand_link_poses(np.concatenate([q_from_pose(T_world_wrist), model.joints_mean[2]]))
    distal = _node(viewer, "/hand/index_distal")
    assert np.asarray(distal.position) == pytest.approx(poses["index_distal"][:3, 3], abs=1e-6)
    _, cov = sah.fingertip_marginals(model.T_object_wrist_mean, model.joints_mean, model.cov)
    ell = _node(viewer, "/marginals/ham/t2/index")
    assert np.asarray(ell.position) == pytest.approx(tips[1], abs=1e-6)
    scale = np.sort(np.asarray(ell.scale))
    R = viewer.scene.T_world_object[:3, :3]
    assert scale == pytest.approx(np.sqrt(np.linalg.eigvalsh(R @ cov[2, 1] @ R.T)), rel=1e-4)
    with pytest.raises(InputError, match="step"):
        viewer.show_step("ham", 8)


def test_draws_are_ghost_hands_coloured_by_pybullets_collision_check(viewer):
    from inference.sampler import sample_marginal

    viewer.show_step("ham", 7)
    viewer.rng = np.random.default_rng(5)
    free = viewer.draw_samples(12)
    T, joints = sample_marginal(viewer.models["ham"], 7, 12, np.random.default_rng(5))
    q = np.concatenate([q_from_pose(viewer.scene.T_world_object @ T), sah.clip_joints(joints)], axis=1)
    with World("ham") as world:
        assert free.tolist() == [world.is_free(qi) for qi in q]
    batch = _node(viewer, "/draws/index_distal")
    assert np.asarray(batch.batched_positions).shape == (12, 3)
    assert np.asarray(batch.batched_colors)[:, 1].tolist() == [180 if f else 50 for f in free]


def test_the_trial_shows_its_path_and_its_closed_grasp_with_contacts(viewer):
    from planning.autograsp import HandCloser

    with World("ham") as world:
        res = HandCloser(world).close(np.asarray(HAM_GRASP_Q))
    assert res.quality > 0.05
    assert viewer.grasp.quality == pytest.approx(res.quality, abs=1e-9)
    n = len(res.contact_points_world)
    assert [_node(viewer, f"/grasp/contacts/{i}") is not None for i in range(n + 1)] == [True] * n + [False]
    viewer.show_waypoint(1.5)  # halfway between waypoints 1 and 2: the wrist height too
    wrist = np.asarray(_node(viewer, "/path/hand/wrist").position)
    assert wrist[2] == pytest.approx(0.5 * (_descent()[1, 2] + _descent()[2, 2]), abs=1e-9)


def test_layers_hide_and_show(viewer):
    viewer.set_visible("draws", False)
    assert _node(viewer, "/draws").visible is False
    viewer.set_visible("draws", True)
    with pytest.raises(InputError, match="layer"):
        viewer.set_visible("ghosts", False)


# -- in a real browser -----------------------------------------------------------------------------------
def _hand_pixels(rgb: np.ndarray) -> int:
    """Pixels of the hand's blue (shaded): blue well above red and green."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return int(np.sum((b > r + 60) & (b > g + 30)))


def _object_pixels(rgb: np.ndarray) -> int:
    """Pixels of the object's orange (shaded): red above green above blue."""
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    return int(np.sum((r > g + 25) & (g > b + 60) & (r > 120)))


@NEEDS_BROWSER
def test_a_headless_chromium_connects_and_shows_the_hand_and_the_object(viewer):
    from pbdgrasp.viewer.browser import screenshot

    viewer.show_step("ham", 0)  # the open hand 15 cm above the can: both in view
    for layer in ("draws", "path", "grasp", "marginals"):
        viewer.set_visible(layer, False)
    try:
        with_hand = screenshot(viewer.server, viewer.look_from, 480, 360)
        viewer.set_visible("hand", False)
        empty = screenshot(viewer.server, viewer.look_from, 480, 360)
    finally:
        for layer in LAYERS:
            viewer.set_visible(layer, True)
    assert with_hand.shape == (360, 480, 3)
    assert _hand_pixels(with_hand) > 0.01 * with_hand[..., 0].size
    assert _hand_pixels(empty) < 0.001 * empty[..., 0].size
    assert _object_pixels(empty) > 0.003 * empty[..., 0].size  # the can is there without the hand
    assert _object_pixels(with_hand) > 0.1 * _object_pixels(empty)  # the hand hides part of it at most


@NEEDS_BROWSER
def test_cli_screenshot_writes_a_png(tmp_path, capsys, ham_top_down_model):
    import imageio.v3 as iio

    from pbdgrasp.cli import main

    ham_top_down_model(8).save(tmp_path / "ham.model.npz")
    out = tmp_path / "shot.png"
    argv = ["view", "--scene", "ham", "--model", str(tmp_path / "ham.model.npz"), "--port", "0"]
    assert main([*argv, "--draws", "5", "--width", "320", "--height", "240", "--screenshot", str(out)]) == 0
    assert iio.imread(out).shape[:2] == (240, 320)
    assert "of 5 draws collision-free" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, expect",
    [
        (["--trial", "1"], "--trial: expected --results"),
        (["--hide", "ghosts"], "--hide: expected layers"),
        (["--step", "99"], "--step: expected"),
        (["--results", "missing.sqlite"], "missing.sqlite"),
    ],
)
def test_cli_errors_are_one_line(extra, expect, tmp_path, capsys, ham_top_down_model, monkeypatch):
    from pbdgrasp.cli import main

    monkeypatch.chdir(tmp_path)
    ham_top_down_model(8).save(tmp_path / "ham.model.npz")
    assert main(["view", "--scene", "ham", "--model", "ham.model.npz", "--port", "0", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and expect in err[0]


def test_cli_without_a_browser_says_so_before_any_work(tmp_path, capsys, monkeypatch):
    from pbdgrasp.cli import main

    monkeypatch.setenv("PBDGRASP_CHROMIUM", str(tmp_path / "no-browser"))
    argv = ["view", "--scene", "ham", "--model", "missing.model.npz", "--screenshot", str(tmp_path / "s.png")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "PBDGRASP_CHROMIUM" in err and not (tmp_path / "s.png").exists()
