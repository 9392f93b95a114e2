"""The demonstrated contacts held at the grasp: the paper's f_4t on the hand's margins to the grasped object
(our use of it; docs/method.md).

The clearance factors (:func:`inference.factors.clearance_factors`) keep the hand out of the object, but a
hinge adds nothing where a margin is positive: near the grasp the marginals keep the whole width of
Sigma_r + Sigma_m towards the object, and most draws of the last steps enter it or close far from it.
Section V-B of the paper enforces "a specific range of constraint values, given by the mean r_t and
covariance R_t" by a prior f_4t on C_t = phi(X_t). Here, at each of the last
``params.contact_steps(grasp_type)`` steps (by default 15 for power grasps, none for precision grasps),
C_t is the margins to the grasped object (distance - object clearance - radius, as in
:mod:`inference.clearance`) of the spheres that tau_r, placed at the scene's object pose, brings within
``params.contact_reach_mm`` of it; r_t is their values in tau_r clipped to ``[0, reach]`` (the
demonstrated contact, outside the clearance), and ``R_t = contact_std^2 I``. Where the scene occupies the
place of a demonstrated contact, the contact gives way to it. For a power grasp (``power_contact_release:
sphere``) a sphere that tau_r brings within ``params.contact_release_mm`` of the table's or an obstacle's
clearance is not held (the lying can's table under the wrap's fingers), and the others still hold the
hand to the object (three chips: the palm on the grasped can while the fingers leave the neighbours). A
precision grasp (``precision_contact_release: step``) is its few fingertip contacts together: a step at
which tau_r has one of them inside that clearance holds none (the jar in a hole: the block takes the
demonstrated contacts, and the grasp moves up as a whole).
Without a scene or an object field there are none.

Where the scene's object is not the demonstration's (a strategy carried to a similar object: the chips
strategy on the bottle), the rows and r_t are tau_r's margins to the *demonstrated* object placed at the
scene's object pose, and the factors hold the same margins to the scene's object: the hand touches the
new object where the demonstration touched its own, instead of keeping the distance that tau_r, made
for the other object, happens to have to it (5 mm more for the bottle's smaller radius).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from retarget.trajectory import Trajectory

from .clearance import ClearanceFn
from .factors import ClearanceBatch
from .params import VariationParams

__all__ = ["ContactPlan", "contact_plan", "contact_factors"]

_EXACT_M = 0.2
"""[m] the contact rows' margins are exact, with Jacobians, up to this (far beyond any contact's reach)."""


@dataclass(frozen=True)
class ContactPlan:
    """The contact rows of a solve: per held step its sphere rows, their targets and their std.

    Attributes:
        clearance: the grasped object's margins alone (``HandClearance.object_only``).
        steps: (k,) the held steps.
        rows: per held step, (m_i,) sphere indices.
        targets_m: per held step, (m_i,) r_t [m].
        stds_m: (k,) the std of each step's rows [m].
    """

    clearance: ClearanceFn
    steps: np.ndarray
    rows: tuple[np.ndarray, ...]
    targets_m: tuple[np.ndarray, ...]
    stds_m: np.ndarray

    @property
    def num_rows(self) -> int:
        return int(sum(len(r) for r in self.rows))


def contact_plan(
    traj: Trajectory,
    params: VariationParams,
    clearance: ClearanceFn | None,
    T_world_object: np.ndarray,
    demonstrated: ClearanceFn | None = None,
) -> ContactPlan | None:
    """The contacts of tau_r at ``T_world_object`` (4, 4) (module docstring); ``demonstrated`` the same
    clearance with the demonstration's object in place of the scene's
    (:meth:`inference.clearance.HandClearance.with_object`), where they differ: the rows and targets are
    taken from it. None where nothing is held (no object field, no held steps, no sphere within reach).
    A clearance without ``environment_only`` (no table, no obstacles) releases nothing."""
    object_only = getattr(clearance, "object_only", None)
    held = params.contact_steps(traj.grasp_type)
    if object_only is None or held == 0:
        return None
    margins_of = object_only(_EXACT_M)
    source = margins_of if demonstrated is None else demonstrated.object_only(_EXACT_M)
    if margins_of is None or source is None:
        return None
    n, reach = traj.num_steps, params.contact_reach_mm * 1e-3
    T_world_object = np.asarray(T_world_object, dtype=float)
    last = np.arange(max(0, n - held), n)
    W = T_world_object @ np.asarray(traj.T_object_wrist)[last]
    J = np.asarray(traj.joints)[last]
    margins = source(T_world_object, W, J)[:, : source.n_spheres]
    env_margins = None
    environment = getattr(clearance, "environment_only", None)
    if environment is not None:  # the margins to the table's and the obstacles' clearance
        release = params.contact_release_mm * 1e-3
        env = environment().reaching(release)
        env_margins = env(T_world_object, W, J)[:, : env.n_spheres]
    whole_step = params.contact_release(traj.grasp_type) == "step"
    steps, rows, targets = [], [], []
    for k, t in enumerate(last):
        within = margins[k] < reach
        if env_margins is not None:
            if not whole_step:
                within &= env_margins[k] > release  # released where the scene is within contact_release_mm
            elif np.any(env_margins[k][within] <= 0.0):
                continue  # the scene occupies one of this step's contacts: the step holds none
        near = np.flatnonzero(within)
        if len(near):
            steps.append(t)
            rows.append(near)
            targets.append(np.clip(margins[k, near], 0.0, reach))
    if not steps:
        return None
    stds = np.full(len(steps), params.contact_std_mm * 1e-3)
    return ContactPlan(margins_of, np.array(steps), tuple(rows), tuple(targets), stds)


def contact_factors(
    plan: ContactPlan, key_o: int | None, steps, T_world_object: np.ndarray | None = None
) -> list[gtsam.CustomFactor]:
    """One Gaussian factor per held step on its rows' margins, ``N(margins; r_t, R_t)``, over ``(O, W_t,
    J_t)`` or, with ``T_world_object`` given, over ``(W_t, J_t)`` with O held there. ``steps``: per step of
    the trajectory ``(key_w, key_j)``. The held steps share one :class:`inference.factors.ClearanceBatch`."""
    fixed = T_world_object is not None
    batch = ClearanceBatch(
        plan.clearance, [steps[t] for t in plan.steps], None if fixed else key_o, T_world_object
    )

    def make(i: int) -> gtsam.CustomFactor:
        rows, target = plan.rows[i], plan.targets_m[i]

        def error(this: gtsam.CustomFactor, values: gtsam.Values, H) -> np.ndarray:
            if H is None:
                return batch.evaluate(i, values, False)[rows] - target
            margins, H_O, H_W, H_J = batch.evaluate(i, values, True)
            blocks = (H_W, H_J) if fixed else (H_O, H_W, H_J)
            for k, block in enumerate(blocks):
                H[k] = np.asfortranarray(block[rows])
            return margins[rows] - target

        noise = gtsam.noiseModel.Isotropic.Sigma(len(rows), float(plan.stds_m[i]))
        keys = list(batch.steps[i]) if fixed else [key_o, *batch.steps[i]]
        return gtsam.CustomFactor(noise, keys, error)

    return [make(i) for i in range(len(plan.steps))]
