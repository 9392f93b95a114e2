"""Synthetic human demonstrations: what a 6-D wrist tracker and a dataglove would have recorded.

We have neither sensor, so for each demonstrated object a final grasp of the human hand model is built
following the paper's strategy (section VIII, Fig. 5-7), and a 20 Hz approach trajectory is played
into it. Steps:

1. **Grasp pose.** A least-squares fit of the wrist pose and the 20 joints puts the fingertip sphere
   centres a few millimetres off chosen contact regions (a stand-off), keeps every finger and palm
   sample out of the object, and stays near a natural wrist orientation and posture.
2. **Closure.** Each contact finger closes its flexion joints (as GraspIt!'s autoGrasp: a touching link
   stops its joint and the joints before it) until its fingertip sphere touches the surface; each
   touching instant is found by bisection on the signed distance (Open3D ``RaycastingScene``).
3. **Check.** At the last step each contact fingertip sphere is within :data:`CONTACT_TOL_M` of the
   surface and no finger or palm sample penetrates more than :data:`PENETRATION_TOL_M`; the penetration
   bound is checked at every step of the noise-free trajectory too. A violation raises
   :class:`GenerationError`.
4. **Trajectory.** A pre-grasp :data:`PREGRASP_DISTANCE_M` away along the approach direction with the
   fingers open; minimum-jerk interpolation of the wrist (on SE(3)) and of the joints, the fingers
   closing in the last part.
5. **Sensor noise.** Temporally correlated (first-order Gauss-Markov) noise added to the noise-free
   motion, see :data:`NOISE`. The file holds the noisy recording and, under separate keys, the
   noise-free motion on which the contact check holds.

Everything random goes through one ``numpy.random.Generator``.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares

import assets
from assets import human_hand, se3
from retarget.demonstration import FINGERS, RATE_HZ, Demonstration, default_object_prior
from retarget.virtual_fingers import virtual_fingers_of

from .hand_geometry import (
    FINGER_RADIUS_M,
    GenerationError,
    HandSamples,
    ObjectDistance,
    hand_samples,
    penetration,
    sample_points,
    to_object,
)
from .strategies import DEMONSTRATED_OBJECTS, STRATEGIES, Strategy

__all__ = [
    "Strategy",
    "GraspReport",
    "GenerationError",
    "STRATEGIES",
    "DEMONSTRATED_OBJECTS",
    "ObjectDistance",
    "HandSamples",
    "hand_samples",
    "sample_points",
    "min_jerk",
    "correlated_noise",
    "generate",
    "object_rng",
    "NOISE",
    "FINGER_RADIUS_M",
]

log = logging.getLogger(__name__)

CONTACT_TOL_M = 0.002
PENETRATION_TOL_M = 0.002
#: Wrist start distance from the grasp [m]: where a human reach-to-grasp starts (30-40 cm away).
PREGRASP_DISTANCE_M = 0.35
#: Sensor noise: per-axis standard deviations of stationary first-order Gauss-Markov processes.
NOISE = {
    "model": "first-order Gauss-Markov (AR(1)) per axis, stationary, correlation time correlation_time_s",
    "tracker_position_sigma_m": 0.005,
    "tracker_rotation_sigma_rad": float(np.deg2rad(2.0)),
    "glove_sigma_rad": float(np.deg2rad(3.0)),
    "correlation_time_s": 0.25,
    "rotation_noise": "right perturbation R_true @ Exp(omega), omega per axis in the wrist frame",
    "position_noise": "added to the wrist position in the object frame",
    "contact_check": "on the noise-free motion (keys T_object_wrist_true, joints_true)",
}


def min_jerk(s: np.ndarray) -> np.ndarray:
    """Minimum-jerk profile 10 s^3 - 15 s^4 + 6 s^5 of ``s`` clipped to [0, 1]."""
    s = np.clip(np.asarray(s, dtype=float), 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s * s)


def correlated_noise(rng: np.random.Generator, n: int, dim: int, sigma: float, dt_s: float, tau_s: float):
    """Stationary first-order Gauss-Markov noise (n, dim) with per-axis standard deviation ``sigma``."""
    a = np.exp(-dt_s / tau_s)
    w = rng.standard_normal((n, dim))
    x = np.empty((n, dim))
    x[0] = sigma * w[0]
    for t in range(1, n):
        x[t] = a * x[t - 1] + sigma * np.sqrt(1.0 - a * a) * w[t]
    return x


@dataclass(frozen=True)
class GraspReport:
    """What the contact check measured on the noise-free final grasp.

    Attributes:
        object: object name.
        tip_gap_mm: (5,) signed distance of each fingertip sphere to the surface [mm] (``FINGERS`` order).
        max_penetration_mm: deepest penetration of any finger or palm sample at the last step [mm].
        max_penetration_trajectory_mm: the same over every step of the noise-free trajectory [mm].
        contact_normals: (5, 3) outward surface normals at the fingertips (object frame).
        normal_angle_deg: (4, 4) angles between the contact normals of index, middle, ring, little.
        closest_pair: the two opposing fingers with the most similar contact normals.
        virtual_fingers: ``retarget.virtual_fingers.virtual_fingers_of`` on the final joints, described.
    """

    object: str
    tip_gap_mm: np.ndarray
    max_penetration_mm: float
    max_penetration_trajectory_mm: float
    contact_normals: np.ndarray
    normal_angle_deg: np.ndarray
    closest_pair: tuple[str, str]
    virtual_fingers: str = ""


#: Restarts of the grasp fit. It starts from the natural posture (no abduction, 0.6 rad flexion); when a
#: fingertip ends farther than ``_FIT_RESTART_MISS_M`` from its goal, it runs again from each thumb posture
#: (cmc_abd, cmc_flex, mcp, ip) [rad] of ``_THUMB_STARTS`` (abducted to its limit; straight, or slightly
#: bent) and the lowest cost wins. From the natural posture alone, a thumb that must reach round an object
#: (a power grasp from the side, thumb up) stays in a local minimum 60-90 mm from its target, on the
#: fingers' side.
_FIT_RESTART_MISS_M = 0.02
_THUMB_STARTS = ((0.7, 0.0, 0.0, 0.0), (0.7, 0.3, 0.3, 0.3))


def _fit(strategy: Strategy, dist: ObjectDistance, samples: HandSamples) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares wrist pose and joints with the fingertips at a stand-off from the targets.

    The fit runs from the natural posture; if a fingertip then misses its goal by more than
    ``_FIT_RESTART_MISS_M``, also from each of ``_THUMB_STARTS``, and the lowest cost wins.
    """
    hand = human_hand
    limits = np.asarray(hand.JOINT_LIMITS, dtype=float)
    names = list(hand.JOINT_NAMES)
    fingers = [f for f in FINGERS if f in strategy.targets]
    c, n = dist.closest(np.array([strategy.targets[f] for f in fingers]))
    rt = np.array([FINGER_RADIUS_M[f] for f in fingers])
    goal = c + n * (rt + strategy.standoff_m)[:, None]
    kk = [FINGERS.index(f) for f in fingers]
    pref = np.clip(
        np.array([0.0 if nm.endswith("_abd") else 0.6 for nm in names]), limits[:, 0], limits[:, 1]
    )
    R0 = strategy.R_object_wrist

    def unpack(x):
        return se3.make_pose(R0 @ se3.so3_exp(x[:3]), x[3:6]), x[6:]

    tip_sigma_m = 0.002

    def residuals(x):
        T, J = unpack(x)
        pts, centres = sample_points(J)
        sd = dist.signed(to_object(T, pts)) - samples.radius
        r = [
            ((to_object(T, centres[kk]) - goal) / tip_sigma_m).ravel(),
            np.maximum(0.0, 0.002 - sd) / 0.0005,
            x[:3] / strategy.orientation_sigma_rad,
            (J - pref) / 1.5,
        ]
        if strategy.palm_gap_m is not None:
            palm = sd[samples.owner == 5]
            r.append(np.atleast_1d((palm.min() - strategy.palm_gap_m) / 0.001))
        return np.concatenate(r)

    lo = np.concatenate([np.full(6, -np.inf), limits[:, 0]])
    hi = np.concatenate([np.full(6, np.inf), limits[:, 1]])

    def solve(thumb):
        J0 = pref.copy()
        if thumb is not None:
            J0[list(hand.FINGER_JOINTS["thumb"])] = thumb
        x0 = np.concatenate([np.zeros(3), strategy.p_object_wrist, np.clip(J0, limits[:, 0], limits[:, 1])])
        sol = least_squares(
            residuals, x0, bounds=(lo, hi), x_scale=np.r_[[0.2] * 3, [0.02] * 3, [0.3] * 20], max_nfev=400
        )
        # the worst fingertip miss from the residuals' first block (no second FK)
        miss = tip_sigma_m * np.linalg.norm(sol.fun[: 3 * len(kk)].reshape(-1, 3), axis=-1).max()
        log.debug("%s: fit from thumb %s: cost %.3g, miss %.4f m", strategy.object, thumb, sol.cost, miss)
        return sol, miss

    best, miss = solve(None)
    if miss > _FIT_RESTART_MISS_M:
        for thumb in _THUMB_STARTS:
            sol, _ = solve(thumb)
            if sol.cost < best.cost:
                best = sol
    return unpack(best.x)


def _refit_finger(
    k: int, strategy: Strategy, T: np.ndarray, J: np.ndarray, dist: ObjectDistance, samples: HandSamples
) -> np.ndarray:
    """Re-fit one finger's 4 joints (wrist and other fingers fixed) with its fingertip on its target."""
    hand = human_hand
    limits = np.asarray(hand.JOINT_LIMITS, dtype=float)
    f = FINGERS[k]
    idx = np.array([i for i, nm in enumerate(hand.JOINT_NAMES) if nm.startswith(f + "_")])
    c, n = dist.closest(np.array([strategy.targets[f]]))
    goal = c[0] + n[0] * FINGER_RADIUS_M[f]
    mine = samples.owner == k

    def residuals(x):
        Jx = J.copy()
        Jx[idx] = x
        pts, centres = sample_points(Jx)
        sd = dist.signed(to_object(T, pts[mine])) - samples.radius[mine]
        return np.concatenate([(to_object(T, centres[k]) - goal) / 0.002, np.maximum(0.0, -sd) / 0.0005])

    sol = least_squares(residuals, J[idx], bounds=(limits[idx, 0], limits[idx, 1]), max_nfev=200)
    out = J.copy()
    out[idx] = sol.x
    return out


def _close_finger(k: int, T: np.ndarray, J: np.ndarray, dist: ObjectDistance, samples: HandSamples):
    """Close finger ``k``'s flexion joints until its fingertip touches (autoGrasp with link stops)."""
    hand = human_hand
    limits = np.asarray(hand.JOINT_LIMITS, dtype=float)
    idx = np.array(samples.flex_joints[FINGERS[k]])
    rate = np.array([1.0, 1.0, 0.8])
    mine = samples.owner == k
    active = np.ones(3, bool)
    J = J.copy()

    def at(s):
        Js = J.copy()
        Js[idx[active]] = np.clip(
            J[idx[active]] + s * rate[active], limits[idx[active], 0], limits[idx[active], 1]
        )
        pts, _ = sample_points(Js)
        sd = dist.signed(to_object(T, pts[mine])) - samples.radius[mine]
        return Js, sd

    for _ in range(3):
        if not active.any():
            break
        _, sd0 = at(0.0)
        if sd0.min() <= 0.0:  # the fit left the finger in the object: open it until it just touches
            a, b = -1.5, 0.0
            if at(a)[1].min() <= 0.0:
                break
            for _ in range(30):
                m = 0.5 * (a + b)
                a, b = (m, b) if at(m)[1].min() > 0.0 else (a, m)
            J, sd = at(a)
            seg = samples.segment[mine][sd.argmin()]
        else:
            grid = np.arange(0.01, 2.0, 0.01)
            hit = None
            for s in grid:
                if at(s)[1].min() <= 0.0:
                    hit = s
                    break
            if hit is None:  # closing never reaches the object: keep the finger where it was
                break
            a, b = hit - 0.01, hit
            for _ in range(30):
                m = 0.5 * (a + b)
                a, b = (m, b) if at(m)[1].min() > 0.0 else (a, m)
            J, sd = at(a)
            seg = samples.segment[mine][sd.argmin()]
        active[: seg + 1] = False
    return J


def _trajectory(strategy: Strategy, T_final: np.ndarray, J_final: np.ndarray, samples: HandSamples):
    hand = human_hand
    limits = np.asarray(hand.JOINT_LIMITS, dtype=float)
    n = int(round(strategy.duration_s * RATE_HZ)) + 1
    t = np.arange(n) / RATE_HZ
    D = t[-1]
    T_pre = T_final.copy()
    T_pre[:3, 3] += PREGRASP_DISTANCE_M * strategy.approach / np.linalg.norm(strategy.approach)
    J_open = J_final.copy()
    flex = np.concatenate([samples.flex_joints[f] for f in FINGERS])
    J_open[flex] = np.clip(np.minimum(J_final[flex], 0.15), limits[flex, 0], limits[flex, 1])
    sw = min_jerk(t / (0.75 * D))
    sj = min_jerk((t - 0.45 * D) / (0.55 * D))
    xi = se3.local(T_pre, T_final)
    T = se3.retract(T_pre, sw[:, None] * xi)
    J = J_open + sj[:, None] * (J_final - J_open)
    return t, T, J


def object_rng(name: str, seed: int) -> np.random.Generator:
    """The noise stream of one object's demonstration for a run seed.

    One child of ``SeedSequence(seed)`` per object, fixed by the object's place in
    :data:`DEMONSTRATED_OBJECTS`, so regenerating one object gives the same file as regenerating all.
    """
    if name not in STRATEGIES:
        raise assets.InputError(
            f"no demonstration strategy for {name!r}; valid names: {', '.join(STRATEGIES)}"
        )
    children = np.random.SeedSequence(seed).spawn(len(DEMONSTRATED_OBJECTS))
    return np.random.default_rng(children[DEMONSTRATED_OBJECTS.index(name)])


def generate(
    name: str, rng: np.random.Generator, seed: int | None = None
) -> tuple[Demonstration, GraspReport]:
    """Generate the demonstration of one object.

    Args:
        name: one of :data:`DEMONSTRATED_OBJECTS`.
        rng: the source of the sensor noise.
        seed: recorded in the header (the seed ``rng`` was made from), if known.

    Returns:
        The demonstration (noisy recording plus noise-free motion) and the contact check's figures.

    Raises:
        InputError: unknown object.
        GenerationError: the final grasp fails the contact or penetration check.
    """
    if name not in STRATEGIES:
        raise assets.InputError(
            f"no demonstration strategy for {name!r}; valid names: {', '.join(STRATEGIES)}"
        )
    st = STRATEGIES[name]
    dist = ObjectDistance(name)
    samples = hand_samples()
    T, J = _fit(st, dist, samples)
    for k, f in enumerate(FINGERS):
        if f in st.targets:
            J = _close_finger(k, T, J, dist, samples)
    _, gaps = penetration(dist, T, J, samples.radius)
    for _ in range(3):  # a finger whose closing missed the object: aim it, then close again
        for k, f in enumerate(FINGERS):
            if f in st.targets and abs(gaps[k]) > 0.5 * CONTACT_TOL_M:
                log.debug("%s: %s missed by %.1f mm after closing; re-fitting it", name, f, gaps[k] * 1e3)
                J = _close_finger(k, T, _refit_finger(k, st, T, J, dist, samples), dist, samples)
        _, gaps = penetration(dist, T, J, samples.radius)
    sd, gaps = penetration(dist, T, J, samples.radius)
    contact = [k for k, f in enumerate(FINGERS) if f in st.targets]
    if np.abs(gaps[contact]).max() > CONTACT_TOL_M or -sd.min() > PENETRATION_TOL_M:
        raise GenerationError(
            f"{name}: fingertip gaps {np.round(gaps * 1e3, 2)} mm, max penetration {-sd.min() * 1e3:.2f} mm "
            f"(tolerances {CONTACT_TOL_M * 1e3} / {PENETRATION_TOL_M * 1e3} mm)"
        )
    t, T_true, J_true = _trajectory(st, T, J, samples)
    pen_traj = max(-penetration(dist, T_true[i], J_true[i], samples.radius)[0].min() for i in range(len(t)))
    if pen_traj > PENETRATION_TOL_M:
        raise GenerationError(f"{name}: the approach penetrates the object by {pen_traj * 1e3:.2f} mm")
    _, centres = sample_points(J)
    _, normals = dist.closest(to_object(T, centres))
    opp = normals[1:]
    ang = np.degrees(np.arccos(np.clip(opp @ opp.T, -1.0, 1.0)))
    off = ang + np.eye(4) * 1e9
    i, j = np.unravel_index(off.argmin(), off.shape)
    report = GraspReport(
        name,
        gaps * 1e3,
        float(-sd.min() * 1e3),
        float(pen_traj * 1e3),
        normals,
        ang,
        (FINGERS[1 + min(i, j)], FINGERS[1 + max(i, j)]),
        virtual_fingers_of(J).describe(),
    )
    dt = 1.0 / RATE_HZ
    tau = NOISE["correlation_time_s"]
    n = len(t)
    e_p = correlated_noise(rng, n, 3, NOISE["tracker_position_sigma_m"], dt, tau)
    e_r = correlated_noise(rng, n, 3, NOISE["tracker_rotation_sigma_rad"], dt, tau)
    e_j = correlated_noise(rng, n, J.size, NOISE["glove_sigma_rad"], dt, tau)
    T_rec = se3.make_pose(T_true[:, :3, :3] @ se3.so3_exp(e_r), T_true[:, :3, 3] + e_p)
    mu, cov = default_object_prior()
    demo = Demonstration(
        T_object_wrist=T_rec,
        joints=J_true + e_j,
        t_s=t,
        object=name,
        grasp_type=st.grasp_type,
        T_world_object_mean=mu,
        cov_object=cov,
        rate_hz=RATE_HZ,
        T_object_wrist_true=T_true,
        joints_true=J_true,
        contact_fingers=tuple(FINGERS[k] for k in contact),
        strategy=st.description,
        noise=dict(NOISE),
        seed=seed,
    )
    log.info(
        "%s: tips %s mm, penetration %.2f mm", name, np.round(report.tip_gap_mm, 2), report.max_penetration_mm
    )
    return demo, report
