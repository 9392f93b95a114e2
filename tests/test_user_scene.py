"""A scene a user writes (``assets/scenes/examples/ham_posts.yaml``, not a Table I row): the variation model
adapts to it, checked against pybullet's collision test of the means (an implementation independent of the
model's sphere cover and distance fields)."""

from __future__ import annotations

from pathlib import Path

import pytest

from pbdgrasp.scene_model import learn_in_scene
from pbdgrasp.strategy import retarget_in_scene
from planning.scene import load_scene
from retarget.demonstration import Demonstration
from retarget.retargeting import RetargetConfig

SCENE = Path(__file__).resolve().parents[1] / "assets" / "scenes" / "examples" / "ham_posts.yaml"


@pytest.fixture(scope="module")
def ham_in_posts():
    """ham's strategy (retargeted in its own scene, the paper's last step for speed) solved in the plain ham
    scene and in the user's scene."""
    config = RetargetConfig(final_grasp="paper")
    traj, _ = retarget_in_scene(Demonstration.load("ham"), load_scene("ham"), config)
    scene = load_scene(SCENE)
    return scene, traj, learn_in_scene(traj, load_scene("ham")), learn_in_scene(traj, scene)


def test_the_example_scene_is_a_scene_by_path_not_a_table_row():
    import assets

    scene = load_scene(SCENE)
    assert scene.name == "ham_posts" and "ham_posts" not in assets.scenes()
    assert {o.label for o in scene.obstacles} == {"post", "salt_box"}


def test_the_model_solved_in_a_users_scene_keeps_its_means_out_of_the_obstacles(
    ham_in_posts, penetrations, wall_steps
):
    """tau_r passes the middle finger through the post (measured: steps 32-48, up to 26 mm deep), and so
    does the model solved without the post (22 steps); solved in the scene, the model converges and no
    mean penetrates the post or the box."""
    scene, traj, plain, adapted = ham_in_posts
    depth = min(d.get("post", 0.0) for d in penetrations(scene, traj.T_object_wrist, traj.joints))
    assert depth < -0.015, depth
    assert len(wall_steps(scene, plain)) >= 10
    assert adapted.converged and adapted.iterations <= adapted.params.max_iterations
    assert len(wall_steps(scene, adapted)) == 0
