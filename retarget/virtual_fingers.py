"""Virtual fingers and the grasp cohesive index (Kang and Ikeuchi 1993, 1997): five human fingers to four.

Paper, section IV: at the last step of the demonstration tau_h the human thumb maps to the SAH thumb;
the four opposing human fingers (index, middle, ring, little) are grouped into ``l - 1 = 3`` *virtual
fingers*, the grouping with the minimal grasp cohesive index, and one real finger of each virtual finger
is followed by one SAH finger. The result is the virtual-finger path tau_v.

Definitions used here (Kang and Ikeuchi group fingers by the similarity of their *effective force
directions*, the unit directions in which the fingertips push on the object):

* The dispersion of a virtual finger with unit force directions ``f_1..f_n`` is ``1 - |mean(f_i)|``:
  0 when all push the same way, up to 1 when they cancel. A single finger has dispersion 0.
* The grasp cohesive index of a grouping is the sum over its virtual fingers of ``n_vf`` times the
  dispersion, so it is 0 for perfectly cohesive virtual fingers. Kang and Ikeuchi state cohesion as a
  similarity to be maximised; the paper minimises an index, so we use the equivalent dissimilarity.
* Virtual fingers are groups of *adjacent* fingers (a virtual finger is a functional unit of
  neighbouring fingers; ``adjacent_only=False`` allows any set partition).
* The effective force direction of a human finger is its fingertip's closing direction: the unit
  velocity of the fingertip in the wrist frame when all the finger's flexion joints flex together
  (:func:`effective_force_directions`). It needs no object model and points into the object for a
  finger in contact.
* The real finger chosen from a virtual finger driving SAH finger ``k`` (index, middle, ring) is the
  human finger of the same name if the group has it, else the group's first (radial-most) member.
"""

from __future__ import annotations

import itertools
import logging
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

__all__ = [
    "HUMAN_FINGERS",
    "OPPOSING_FINGERS",
    "ROBOT_FINGERS",
    "VirtualFingers",
    "dispersion",
    "grasp_cohesive_index",
    "groupings",
    "choose_virtual_fingers",
    "effective_force_directions",
    "virtual_fingers_of",
]

log = logging.getLogger(__name__)

HUMAN_FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring", "little")
OPPOSING_FINGERS: tuple[str, ...] = HUMAN_FINGERS[1:]
ROBOT_FINGERS: tuple[str, ...] = ("thumb", "index", "middle", "ring")
#: Joint increment of the numerical closing direction [rad].
_FLEX_STEP_RAD = 1e-4


@dataclass(frozen=True)
class VirtualFingers:
    """The chosen virtual fingers of a grasp.

    Attributes:
        groups: the opposing virtual fingers, radial to ulnar, e.g. ``(("index",), ("middle", "ring"),
            ("little",))``; they drive the SAH index, middle and ring fingers in that order.
        human_for_robot: the human finger followed by each SAH finger (:data:`ROBOT_FINGERS` order),
            e.g. ``("thumb", "index", "middle", "little")``.
        cohesive_index: the grasp cohesive index of ``groups`` (minimal over the candidates).
        candidates: every grouping considered with its index, best first.
    """

    groups: tuple[tuple[str, ...], ...]
    human_for_robot: tuple[str, ...]
    cohesive_index: float
    candidates: tuple[tuple[tuple[tuple[str, ...], ...], float], ...]

    @property
    def human_indices(self) -> tuple[int, ...]:
        """Indices into :data:`HUMAN_FINGERS` of :attr:`human_for_robot`."""
        return tuple(HUMAN_FINGERS.index(f) for f in self.human_for_robot)

    def describe(self) -> str:
        """One line, e.g. ``VF {index} {middle+ring} {little}; SAH <- thumb, index, middle, little``."""
        groups = " ".join("{" + "+".join(g) + "}" for g in self.groups)
        return f"VF {groups} (index {self.cohesive_index:.4f}); SAH <- {', '.join(self.human_for_robot)}"


def _unit(v: np.ndarray) -> np.ndarray:
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    if np.any(n < 1e-12) or not np.all(np.isfinite(v)):
        raise ValueError("force directions must be finite non-zero vectors")
    return v / n


def dispersion(directions: np.ndarray) -> float:
    """``1 - |mean of the unit directions|`` of one virtual finger, (n, 3) -> [0, 1]."""
    return float(1.0 - np.linalg.norm(_unit(directions).mean(axis=0)))


def grasp_cohesive_index(directions: np.ndarray, groups: Sequence[Sequence[int]]) -> float:
    """The grasp cohesive index of a grouping: ``sum_vf n_vf * dispersion(vf)`` (0 = perfectly cohesive).

    Args:
        directions: (m, 3) effective force directions of the fingers (need not be unit).
        groups: the virtual fingers as index lists into ``directions``.
    """
    d = _unit(directions)
    return float(sum(len(g) * dispersion(d[list(g)]) for g in groups))


def groupings(n: int, k: int, adjacent_only: bool = True) -> list[tuple[tuple[int, ...], ...]]:
    """All partitions of fingers ``0..n-1`` into ``k`` non-empty groups, each group sorted, groups by first.

    With ``adjacent_only`` only groups of consecutive fingers (cuts of the ordered list).
    """
    if not 1 <= k <= n:
        raise ValueError(f"cannot group {n} fingers into {k} virtual fingers")
    if adjacent_only:
        out = []
        for cuts in itertools.combinations(range(1, n), k - 1):
            bounds = (0, *cuts, n)
            out.append(tuple(tuple(range(a, b)) for a, b in itertools.pairwise(bounds)))
        return out
    out = set()
    for labels in itertools.product(range(k), repeat=n):
        if len(set(labels)) != k:
            continue
        groups = [tuple(i for i in range(n) if labels[i] == g) for g in range(k)]
        out.add(tuple(sorted(groups)))
    return sorted(out)


def choose_virtual_fingers(
    directions: np.ndarray, n_virtual: int = 3, adjacent_only: bool = True
) -> VirtualFingers:
    """The grouping of the four opposing fingers with the minimal grasp cohesive index.

    Args:
        directions: (4, 3) effective force directions of index, middle, ring, little (any frame).
        n_virtual: number of opposing virtual fingers, ``l - 1`` (3 for the SAH).
        adjacent_only: restrict virtual fingers to neighbouring fingers.

    Returns:
        The :class:`VirtualFingers`; ties go to the earlier grouping of :func:`groupings` (radial first).

    Raises:
        ValueError: ``directions`` is not (4, 3) finite non-zero, or ``n_virtual`` is not 1..3 (the SAH
            has three opposing fingers, so more virtual fingers than that cannot be mapped).
    """
    directions = np.asarray(directions, dtype=float)
    if directions.shape != (len(OPPOSING_FINGERS), 3):
        raise ValueError(
            f"directions: expected shape (4, 3) for {OPPOSING_FINGERS}, found {directions.shape}"
        )
    if not 1 <= n_virtual <= len(ROBOT_FINGERS) - 1:
        raise ValueError(f"n_virtual: expected 1..{len(ROBOT_FINGERS) - 1}, found {n_virtual}")
    scored = [
        (
            tuple(tuple(OPPOSING_FINGERS[i] for i in g) for g in grouping),
            grasp_cohesive_index(directions, grouping),
        )
        for grouping in groupings(len(OPPOSING_FINGERS), n_virtual, adjacent_only)
    ]
    ranked = sorted(enumerate(scored), key=lambda item: (round(item[1][1], 12), item[0]))
    best_groups, best_index = ranked[0][1]
    robot_targets = ROBOT_FINGERS[1 : 1 + n_virtual]
    chosen = tuple(
        target if target in g else g[0] for g, target in zip(best_groups, robot_targets, strict=True)
    )
    result = VirtualFingers(
        groups=best_groups,
        human_for_robot=("thumb", *chosen),
        cohesive_index=best_index,
        candidates=tuple(s for _, s in ranked),
    )
    log.info("virtual fingers: %s", result.describe())
    return result


def effective_force_directions(joints: np.ndarray) -> np.ndarray:
    """Closing directions of the five human fingertips in the wrist frame, (20,) -> (5, 3) unit.

    The fingertip velocity when every flexion joint of the finger (all its joints but the abduction
    ones) increases together, by central differences of :func:`assets.human_hand.fingertip_positions`.
    """
    from assets import human_hand

    joints = np.asarray(joints, dtype=float)
    out = np.zeros((len(HUMAN_FINGERS), 3))
    for k, finger in enumerate(HUMAN_FINGERS):
        flex = [
            i
            for i, name in enumerate(human_hand.JOINT_NAMES)
            if name.startswith(finger + "_") and "abd" not in name and "rot" not in name
        ]
        step = np.zeros_like(joints)
        step[flex] = _FLEX_STEP_RAD
        p_plus = human_hand.fingertip_positions(joints + step)[k]
        p_minus = human_hand.fingertip_positions(joints - step)[k]
        out[k] = p_plus - p_minus
    return _unit(out)


def virtual_fingers_of(
    joints_last: np.ndarray, n_virtual: int = 3, adjacent_only: bool = True
) -> VirtualFingers:
    """Virtual fingers of a human hand posture (the last step of tau_h), (20,) joints [rad]."""
    directions = effective_force_directions(joints_last)
    return choose_virtual_fingers(directions[1:], n_virtual=n_virtual, adjacent_only=adjacent_only)
