"""The interactive 3-D viewer of strategies in a scene: a viser server (any browser shows it).

:class:`StrategyViewer` serves, in the world frame of one scene (metres, z up, the table top at z = 0):

=================================  =============================================================
scene node                         what
=================================  =============================================================
``/scene/<part>``                  the table, the target object, each obstacle (by its label)
``/hand/<link>``                   the SAH at the selected strategy's mean of the current step
``/marginals/<model>/t<k>/<tip>``  1-sigma ellipsoid of a fingertip's marginal at step k (Fig. 3)
``/marginals/<model>/paths``       the fingertips' mean paths (line segments)
``/draws/<link>``                  draws of the current step as translucent hands (batched)
``/path/hand/<link>``              a stored trial's planned path: the hand at a waypoint
``/path/wrist_path``               the path's wrist positions (line segments)
``/grasp/hand/<link>``             the trial's grasp closed by autograsp
``/grasp/contacts/<i>``            its contact points on the object; ``/grasp/normals`` (into the
                                   object, 3 cm), ``/grasp/label`` (its epsilon)
=================================  =============================================================

A model's marginals P(X_t | O) are shown at the scene's object pose (the object frame's means and
covariances moved by ``scene.T_world_object``), conditioned on the object there as the model's are on
mu_o. The fingertip ellipsoids are the linearized push-forward :func:`assets.sah.fingertip_marginals`.
Draws are ``sample_marginal`` draws with the joints clipped to the limits, coloured by a pybullet
collision check (green free, red in collision). The viewer's randomness comes from the
``numpy.random.Generator`` it is given.
"""

from __future__ import annotations

import json
import threading
import time
from dataclasses import dataclass

import numpy as np
import viser

from assets import sah
from assets.errors import InputError
from assets.se3 import q_from_pose
from inference.model import VariationModel
from inference.sampler import sample_marginal
from pbdgrasp.results_db import TrialRecord
from planning.camera import default_camera
from planning.config_space import HandConfigSpace
from planning.scene import Scene
from planning.world import World

from . import LAYERS
from .meshes import ellipsoid_scale_wxyz, hand_link_meshes, hand_link_poses, scene_meshes, wxyz_of

__all__ = ["HAND_RGB", "FINGER_RGB", "LAYERS", "StrategyViewer", "trial_path"]


HAND_RGB = (70, 120, 230)
"""The hand's colour (blue, apart from the scene's browns and greens and from the draws' colours)."""
FINGER_RGB = {
    "thumb": (228, 26, 28),
    "index": (55, 126, 184),
    "middle": (77, 175, 74),
    "ring": (152, 78, 163),
}
FREE_RGB, COLLIDING_RGB, CONTACT_RGB = (40, 180, 80), (220, 50, 40), (250, 220, 0)
MAX_DRAWS = 200


def trial_path(trial: TrialRecord) -> np.ndarray:
    """The planned path (K, 19) [m, rad] stored with a trial (empty (0, 19) if none was stored)."""
    path = json.loads(trial.grasp_json).get("path", [])
    return np.asarray(path, dtype=float).reshape(-1, 19)


@dataclass
class _Hand:
    """One hand's scene nodes, a mesh per link, moved together."""

    handles: dict

    def move(self, q: np.ndarray) -> None:
        poses = hand_link_poses(q)
        for link, h in self.handles.items():
            h.position, h.wxyz = poses[link][:3, 3], wxyz_of(poses[link][:3, :3])

    def show(self, visible: bool) -> None:
        for h in self.handles.values():
            h.visible = visible


class StrategyViewer:
    """Serve a scene, strategies' marginals, a trial's path and grasp on ``http://host:port``.

    Args:
        scene: the scene (world frame).
        models: label -> variation model (its marginals are shown at the scene's object).
        trial: a stored trial of this scene (its path and grasp), or None.
        rng: the generator of the draws.
        host, port: where to listen (port 0: a free one).

    Raises:
        InputError: no model and no trial to show.
    """

    def __init__(
        self,
        scene: Scene,
        models: dict[str, VariationModel],
        trial: TrialRecord | None,
        rng: np.random.Generator,
        host: str = "127.0.0.1",
        port: int = 8080,
    ):
        if not models and trial is None:
            raise InputError("view: expected a model (--model) or a trial (--results) to show")
        self.scene, self.models, self.trial, self.rng = scene, dict(models), trial, rng
        self._world = World(scene, hand="sah")
        self._lock = threading.Lock()
        self.server = None
        try:
            self.server = viser.ViserServer(host=host, port=port, verbose=False)
            self._build()
        except BaseException:
            self.close()
            raise

    def _build(self) -> None:
        self.server.scene.set_up_direction("+z")
        self._layers = {name: self.server.scene.add_frame(f"/{name}", show_axes=False) for name in LAYERS}
        self._add_scene()
        self._links = hand_link_meshes("sah")
        self.hand = self._add_hand("/hand", HAND_RGB)
        self.model_label = next(iter(self.models), None)
        self.step = 0
        self._ellipsoids: dict[str, list[list]] = {}
        for label, model in self.models.items():
            self._add_marginals(label, model)
        self._path = trial_path(self.trial) if self.trial is not None else np.zeros((0, 19))
        self._all_steps = self._draw_text = self._trial_text = None
        self._gui()
        if self.model_label is not None:
            self.show_step(self.model_label, self.models[self.model_label].num_steps - 1)
        else:
            self.hand.show(False)
        if self.trial is not None:
            self._add_trial()

    @property
    def url(self) -> str:
        return f"http://{self.server.get_host()}:{self.server.get_port()}"

    # -- static parts ---------------------------------------------------------------------------------------
    def _add_scene(self) -> None:
        for part in scene_meshes(self.scene):
            self.server.scene.add_mesh_simple(
                f"/scene/{part.name}",
                part.mesh.vertices,
                part.mesh.faces,
                color=part.rgb,
                position=part.T_world_mesh[:3, 3],
                wxyz=wxyz_of(part.T_world_mesh[:3, :3]),
            )

    def _add_hand(self, root: str, rgb, opacity: float | None = None) -> _Hand:
        handles = {
            link: self.server.scene.add_mesh_simple(
                f"{root}/{link}", mesh.vertices, mesh.faces, color=rgb, opacity=opacity
            )
            for link, mesh in self._links.items()
        }
        return _Hand(handles)

    def _add_marginals(self, label: str, model: VariationModel) -> None:
        T_wo = self.scene.T_world_object
        mean, cov = sah.fingertip_marginals(model.T_object_wrist_mean, model.joints_mean, model.cov)
        mean = mean @ T_wo[:3, :3].T + T_wo[:3, 3]
        cov = T_wo[:3, :3] @ cov @ T_wo[:3, :3].T
        scale, wxyz = ellipsoid_scale_wxyz(cov)
        nodes = []
        for k in range(model.num_steps):
            nodes.append(
                [
                    self.server.scene.add_icosphere(
                        f"/marginals/{label}/t{k}/{finger}",
                        radius=1.0,
                        subdivisions=2,
                        scale=tuple(np.maximum(scale[k, i], 1e-5)),
                        wxyz=wxyz[k, i],
                        position=mean[k, i],
                        color=FINGER_RGB[finger],
                        opacity=0.35,
                        cast_shadow=False,
                        visible=False,
                    )
                    for i, finger in enumerate(sah.FINGERS)
                ]
            )
        self._ellipsoids[label] = nodes
        segments = np.stack([mean[:-1], mean[1:]], axis=2).reshape(-1, 2, 3)  # (T-1) x 4 fingers
        colors = np.tile(np.array([FINGER_RGB[f] for f in sah.FINGERS]), (model.num_steps - 1, 1))
        self.server.scene.add_line_segments(
            f"/marginals/{label}/paths",
            segments,
            np.repeat(colors[:, None], 2, axis=1),
            thickness=2.0,
            thickness_units="screen",
        )

    # -- the strategy ---------------------------------------------------------------------------------------
    def _world_q(self, T_object_wrist: np.ndarray, joints: np.ndarray) -> np.ndarray:
        """Configurations (..., 19) in the world frame of wrist poses in the object frame and joints."""
        T = self.scene.T_world_object @ T_object_wrist
        return np.concatenate([q_from_pose(T), joints], axis=-1)

    def mean_q(self, label: str, k: int) -> np.ndarray:
        """The configuration (19,) of model ``label``'s mean at step k in the world frame."""
        return self.models[label].world_means(self.scene.T_world_object)[k]

    def show_step(self, label: str, k: int) -> None:
        """Put the hand at model ``label``'s mean of step k and show that step's ellipsoids."""
        model = self.models[label]
        if not 0 <= k < model.num_steps:
            raise InputError(f"step: expected 0..{model.num_steps - 1}, found {k}")
        self.model_label, self.step = label, int(k)
        self.hand.move(self.mean_q(label, k))
        every = self._all_steps is not None and bool(self._all_steps.value)
        for other, nodes in self._ellipsoids.items():
            for j, row in enumerate(nodes):
                wanted = other == label and (j == k or every)
                for h in row:
                    if h.visible != wanted:  # a message to every client only where it changes
                        h.visible = wanted

    def draw_samples(self, n: int) -> np.ndarray:
        """Show ``n`` draws of the current step as ghost hands; returns which are collision-free (n,) bool."""
        n = int(np.clip(n, 1, MAX_DRAWS))
        model = self.models[self.model_label]
        T_ow, joints = sample_marginal(model, self.step, n, self.rng)
        q = self._world_q(T_ow, sah.clip_joints(joints))
        with self._lock:
            free = np.array([self._world.is_free(qi) for qi in q])
        poses = hand_link_poses(q)
        colors = np.where(free[:, None], FREE_RGB, COLLIDING_RGB).astype(np.uint8)
        for link, mesh in self._links.items():
            self.server.scene.add_batched_meshes_simple(
                f"/draws/{link}",
                mesh.vertices,
                mesh.faces,
                batched_wxyzs=wxyz_of(poses[link][:, :3, :3]),
                batched_positions=poses[link][:, :3, 3],
                batched_colors=colors,
                opacity=0.3,
                cast_shadow=False,
            )
        self._draw_text.content = f"step {self.step}: **{int(free.sum())} of {n}** draws collision-free"
        return free

    # -- a stored trial -------------------------------------------------------------------------------------
    def _add_trial(self) -> None:
        if len(self._path):
            self.path_hand = self._add_hand("/path/hand", HAND_RGB, opacity=0.6)
            wrist = self._path[:, :3]
            self.server.scene.add_line_segments(
                "/path/wrist_path",
                np.stack([wrist[:-1], wrist[1:]], axis=1),
                (30, 30, 30),
                thickness=2.0,
                thickness_units="screen",
            )
            self.show_waypoint(len(self._path) - 1)
        grasp = json.loads(self.trial.grasp_json)
        q = grasp.get("q", grasp.get("closed_q"))
        if q is None:
            return
        from planning.autograsp import HandCloser

        with self._lock:
            res = HandCloser(self._world).close(np.asarray(q, dtype=float))
        self.grasp = res
        self._add_hand("/grasp/hand", HAND_RGB).move(res.closed_q)
        if len(res.contact_points_world):
            for i, p in enumerate(res.contact_points_world):
                self.server.scene.add_icosphere(
                    f"/grasp/contacts/{i}", radius=0.004, color=CONTACT_RGB, position=p
                )
            tips = res.contact_points_world + 0.03 * res.contact_normals_world
            self.server.scene.add_line_segments(
                "/grasp/normals",
                np.stack([res.contact_points_world, tips], axis=1),
                CONTACT_RGB,
                thickness=3.0,
                thickness_units="screen",
            )
        top = res.closed_q[:3] + [0.0, 0.0, 0.12]
        self.server.scene.add_label("/grasp/label", f"epsilon {res.quality:.3f}", position=top)
        self._trial_text.content = (
            f"trial {self.trial.trial} ({self.trial.planner}): "
            f"{'solved' if self.trial.success else 'not solved'}, "
            f"stored epsilon {self.trial.quality:.3f}, closed again {res.quality:.3f}, "
            f"{len(res.contact_links)} contacts, {len(self._path)} waypoints"
        )

    def show_waypoint(self, i: int) -> None:
        """Put the path hand at waypoint i (a float interpolates between waypoints)."""
        if not len(self._path):
            raise InputError("this trial stored no path")
        i = float(np.clip(i, 0, len(self._path) - 1))
        a = int(np.floor(i))
        b = min(a + 1, len(self._path) - 1)
        self.path_hand.move(HandConfigSpace().interpolate(self._path[a], self._path[b], i - a))

    # -- controls -------------------------------------------------------------------------------------------
    def _gui(self) -> None:
        gui = self.server.gui
        if self.models:
            with gui.add_folder("Strategy"):
                pick = gui.add_dropdown("model", tuple(self.models), initial_value=self.model_label)
                T = self.models[self.model_label].num_steps
                step = gui.add_slider("step", min=0, max=T - 1, step=1, initial_value=T - 1)
                self._all_steps = gui.add_checkbox("ellipsoids of all steps", initial_value=False)
                count = gui.add_slider("draws", min=1, max=MAX_DRAWS, step=1, initial_value=20)
                draw = gui.add_button("draw from this step")
                self._draw_text = gui.add_markdown("")

            @pick.on_update
            def _(_):
                step.max = self.models[pick.value].num_steps - 1
                self.show_step(pick.value, min(int(step.value), int(step.max)))

            step.on_update(lambda _: self.show_step(pick.value, int(step.value)))
            self._all_steps.on_update(lambda _: self.show_step(self.model_label, self.step))
            draw.on_click(lambda _: self.draw_samples(int(count.value)))
        with gui.add_folder("Layers", expand_by_default=False):
            for name in LAYERS:
                box = gui.add_checkbox(name, initial_value=True)
                box.on_update(lambda event, name=name: self.set_visible(name, event.target.value))
        if self.trial is not None:
            with gui.add_folder("Trial"):
                self._trial_text = gui.add_markdown("")
                if len(self._path):
                    k = len(self._path) - 1
                    way = gui.add_slider("waypoint", min=0, max=k, step=0.1, initial_value=k)
                    play = gui.add_button("play the path")
                    way.on_update(lambda _: self.show_waypoint(way.value))

                    @play.on_click
                    def _(_):
                        for s in np.linspace(0, k, 20 * max(k, 1) + 1):
                            way.value = float(s)
                            time.sleep(0.03)

    def set_visible(self, layer: str, visible: bool) -> None:
        """Show or hide one of :data:`LAYERS` with everything under it."""
        if layer not in self._layers:
            raise InputError(f"layer: expected one of {', '.join(LAYERS)}, found {layer!r}")
        self._layers[layer].visible = bool(visible)

    def look_from(self, client, view: str = "side", distance_m: float = 0.65) -> None:
        """Point a client's camera at the object from where :func:`planning.camera.default_camera` looks,
        ``distance_m`` from its target."""
        cam = default_camera(self.scene, view)
        target, eye = np.asarray(cam["target"], dtype=float), np.asarray(cam["eye"], dtype=float)
        eye = target + distance_m * (eye - target) / np.linalg.norm(eye - target)
        client.camera.up_direction = tuple(cam["up"])
        client.camera.position = tuple(eye)
        client.camera.look_at = tuple(cam["target"])
        client.camera.fov = np.radians(cam["fov_deg"])

    def close(self) -> None:
        """Stop the server and free the pybullet world (idempotent)."""
        if self.server is not None:
            self.server.stop()
            self.server = None
        self._world.close()
