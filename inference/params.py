"""Parameters of the variation model (paper sections IV-VI): one frozen dataclass, loaded from YAML.

Every field has the paper's default (or a documented choice where the paper is silent); a YAML file
(``pbdgrasp infer --params P.yaml``) sets any subset of them by name, unknown names are an error::

    # modelling error Sigma_m (paper section IV): fingertip, wrist position and orientation stds
    precision_fingertip_std_mm: 8.0
    precision_wrist_position_std_mm: 5.0
    precision_wrist_rotation_std_deg: 2.0
    power_fingertip_std_mm: 18.0          # +10 mm for power grasps (finger curvature not optimized)
    power_wrist_position_std_mm: 15.0     # +10 mm
    power_wrist_rotation_std_deg: 2.0
    joint_floor_std_deg: 1.0              # added to every joint's variance: keeps f_1t positive definite
    fingertip_cov_map: by_scene           # configuration where the scene needs it, else finger_joints
    by_scene_depth_mm: 20.0               # tau_r this deep in the scene's clearance: all configuration
    by_scene_steps: 5                     # ... and this many steps before and after it
    # smoothness S_t between consecutive steps (per step of the trajectory, 20 Hz in the demonstrations)
    smooth_position_std_mm: 10.0          # the paper's S_t = 10^2 I mm^2
    smooth_rotation_std_deg: 5.0          # our choice: ~100 deg/s at 20 Hz
    smooth_joint_std_deg: 5.0             # our choice: ~100 deg/s at 20 Hz
    # configuration-space overrides: 19 stds [omega (3, rad), v (3, m), joints (13, rad)]; replace the above
    sigma_m_std_config: null
    smoothness_std_config: null
    # clearance factors f_3t, f_4t (section V-B), used only with a scene: hinges on the clearance
    clearance_mm: 10.0                    # of the hand's spheres from the table and the obstacles
    precision_object_clearance_mm: 3.0    # from the grasped object, precision grasps (6: freer, weaker)
    power_object_clearance_mm: 3.0        # power grasps: palm and phalanges near it (8: no chips grasp)
    self_clearance_mm: 5.0                # between spheres of phalanges of different fingers (was 2)
    constraint_std_mm: 2.0                # R_t = constraint_std^2, the std of each hinge row
    hinge_smoothing_mm: 0.5               # the hinge's smoothing length (inference.factors.clearance_error)
    # the demonstrated contacts held at the grasp: f_4t on the margins to the object (inference.contact)
    precision_contact_steps: 0            # the last steps that hold them, precision grasps (0: none)
    power_contact_steps: 15               # ... power grasps
    contact_reach_mm: 10.0                # spheres of tau_r this near the object (beyond its clearance) hold
    contact_std_mm: 2.0                   # R_t = contact_std^2 I
    contact_release_mm: 20.0              # but not a sphere this near the table's or an obstacle's clearance
    precision_contact_release: step       # ... nor, for precision grasps, the rest of that sphere's step
    power_contact_release: sphere         # ... power grasps: the sphere alone
    # joint limits by expectation propagation (with solve(..., joint_limits=...); ours, see model.py)
    joint_limit_min_probability: 1.0e-4   # a joint whose marginal puts more beyond a limit gets a site
    joint_limit_damping: 0.5              # fraction of a site update applied (natural parameters)
    joint_limit_max_iterations: 50        # EP updates on the final graph
    joint_limit_tolerance: 1.0e-3         # stop when no joint's marginal mean or std moves more [rad]
    # the clearance in the marginals by expectation propagation (inference.clearance_sites), with a scene
    clearance_sites: false                # true: also sites (draws clear the scene; docs/method.md)
    clearance_site_min_probability: 1.0e-3  # a margin whose marginal puts more below 0 gets a site
    clearance_site_reach_mm: 50.0         # margins up to this are evaluated exactly for the sites
    clearance_site_damping: 0.5           # fraction of a site update applied (natural parameters)
    clearance_site_object: false          # also the grasped object's clearance (true: the grasps stand off)
    clearance_site_softmin_mm: 1.0        # one site per link: the soft minimum of its spheres' margins
    backward_sweep: true                  # a solve that leaves a link in the scene: retry from the grasp back
    clearance_site_tolerance: 0.1         # stop when no step's marginal mean or std moves more, in its stds
    # GTSAM's Levenberg-Marquardt (section VI: the optimizer relinearizes every factor per iteration)
    max_iterations: 100                   # per solve
    relative_error_tolerance: 1.0e-5      # converged when the error decreases relatively less than this
    site_solve_tolerance: 1.0e-3          # ... the solves between site updates (the last: the above)

Sigma_m in configuration space is built by :func:`inference.factors.modeling_covariance`: the fingertip
covariance (12x12, 4 fingertips x 3) is mapped with the pseudo-inverse of the fingertip Jacobian
(:func:`assets.sah.config_cov_from_fingertip_cov`): by default of the whole Jacobian
(``configuration``: the minimum-norm configuration change, wrist and joints coupled), or of its joint
columns alone (``finger_joints``: the fingers' joints carry the fingertip std, the wrist its own stds,
independent). By default (``by_scene``) the scene chooses per step: the model's wrist can only move
round an obstacle where Sigma_m couples it to the fingers, but where nothing is in the way the coupled
map trades the wrist for the fingers and stands the grasp back. The weight of ``configuration`` at step
t is ``clip(-m_t / by_scene_depth_mm, 0, 1)``, with ``m_t`` the smallest margin of tau_r(t), placed at
the scene's object pose, to the table and the obstacles (clearance ``clearance_mm`` included; not the
grasped object, not the hand itself), taken as the largest over ``by_scene_steps`` steps before and after;
``finger_joints`` has the rest (:func:`inference.graph.configuration_weights`). Without a scene it is
``finger_joints`` throughout. The wrist stds are added on the ``[omega, v]`` block, and the joint floor
on the joint block. With ``sigma_m_std_config`` set, Sigma_m is ``diag(sigma_m_std_config^2)`` instead
(the floor is still added; set ``joint_floor_std_deg: 0`` to state the covariance exactly).
"""

from __future__ import annotations

import dataclasses
import math
import os
from dataclasses import dataclass, field

import numpy as np
import yaml

from assets.errors import InputError
from assets.io import is_number
from assets.q_layout import Q_DIM
from assets.sah import FINGERTIP_COV_MAPS

__all__ = ["VariationParams", "SIGMA_M_MAPS"]

_INT_FIELDS = (
    "max_iterations",
    "joint_limit_max_iterations",
    "by_scene_steps",
    "precision_contact_steps",
    "power_contact_steps",
)
_MAY_BE_ZERO = ("by_scene_steps", "precision_contact_steps", "power_contact_steps")

CONTACT_RELEASES = ("sphere", "step")
"""The values of ``<grasp type>_contact_release``: where the scene is near a held sphere, release that
sphere alone or every sphere of its step (:mod:`inference.contact`)."""

SIGMA_M_MAPS = (*FINGERTIP_COV_MAPS, "by_scene")
"""The values of ``fingertip_cov_map``: the two maps of :func:`assets.sah.config_cov_from_fingertip_cov`
and their per-step blend by the scene."""


@dataclass(frozen=True)
class VariationParams:
    """All parameters of the variation model; see the module docstring for meaning and units."""

    precision_fingertip_std_mm: float = 8.0
    precision_wrist_position_std_mm: float = 5.0
    precision_wrist_rotation_std_deg: float = 2.0
    power_fingertip_std_mm: float = 18.0
    power_wrist_position_std_mm: float = 15.0
    power_wrist_rotation_std_deg: float = 2.0
    joint_floor_std_deg: float = 1.0
    fingertip_cov_map: str = "by_scene"
    by_scene_depth_mm: float = 20.0
    by_scene_steps: int = 5
    smooth_position_std_mm: float = 10.0
    smooth_rotation_std_deg: float = 5.0
    smooth_joint_std_deg: float = 5.0
    sigma_m_std_config: tuple[float, ...] | None = field(default=None)
    smoothness_std_config: tuple[float, ...] | None = field(default=None)
    clearance_mm: float = 10.0
    precision_object_clearance_mm: float = 3.0
    power_object_clearance_mm: float = 3.0
    self_clearance_mm: float = 5.0
    constraint_std_mm: float = 2.0
    hinge_smoothing_mm: float = 0.5
    precision_contact_steps: int = 0
    power_contact_steps: int = 15
    contact_reach_mm: float = 10.0
    contact_std_mm: float = 2.0
    contact_release_mm: float = 20.0
    precision_contact_release: str = "step"
    power_contact_release: str = "sphere"
    joint_limit_min_probability: float = 1e-4
    joint_limit_damping: float = 0.5
    joint_limit_max_iterations: int = 50
    joint_limit_tolerance: float = 1e-3
    clearance_sites: bool = False
    clearance_site_min_probability: float = 1e-3
    clearance_site_reach_mm: float = 50.0
    clearance_site_damping: float = 0.5
    clearance_site_object: bool = False
    clearance_site_softmin_mm: float = 1.0
    backward_sweep: bool = True
    clearance_site_tolerance: float = 0.1
    max_iterations: int = 100
    relative_error_tolerance: float = 1e-5
    site_solve_tolerance: float = 1e-3

    def __post_init__(self):
        for f in dataclasses.fields(self):
            value = getattr(self, f.name)
            if f.name in ("sigma_m_std_config", "smoothness_std_config"):
                if value is None:
                    continue
                arr = np.asarray(value, dtype=float) if _is_numeric_seq(value) else None
                if arr is None or arr.shape != (Q_DIM,):
                    raise InputError(
                        f"{f.name}: expected 19 numbers [omega (rad), v (m), joints (rad)], found {value!r}"
                    )
                if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
                    raise InputError(f"{f.name}: every std must be finite and > 0, found {arr.tolist()}")
                object.__setattr__(self, f.name, tuple(float(x) for x in arr))
                continue
            if f.name == "fingertip_cov_map":
                if value not in SIGMA_M_MAPS:
                    raise InputError(f"{f.name}: expected one of {', '.join(SIGMA_M_MAPS)}, found {value!r}")
                continue
            if f.name in ("precision_contact_release", "power_contact_release"):
                if value not in CONTACT_RELEASES:
                    raise InputError(
                        f"{f.name}: expected one of {', '.join(CONTACT_RELEASES)}, found {value!r}"
                    )
                continue
            if f.name in ("clearance_sites", "clearance_site_object", "backward_sweep"):
                if not isinstance(value, bool):
                    raise InputError(f"{f.name}: expected true or false, found {value!r}")
                continue
            is_int = f.name in _INT_FIELDS
            if not is_number(value):
                raise InputError(f"{f.name}: expected a number, found {value!r}")
            if is_int:
                least = 0 if f.name in _MAY_BE_ZERO else 1
                if not math.isfinite(value) or int(value) != value or value < least:
                    raise InputError(f"{f.name}: expected an integer >= {least}, found {value!r}")
                object.__setattr__(self, f.name, int(value))
                continue
            value = float(value)
            if f.name in ("joint_limit_damping", "clearance_site_damping") and not 0.0 < value <= 1.0:
                raise InputError(f"{f.name}: expected a fraction in (0, 1], found {value!r}")
            is_probability = f.name in ("joint_limit_min_probability", "clearance_site_min_probability")
            if is_probability and not 0.0 < value < 1.0:
                raise InputError(f"{f.name}: expected a probability in (0, 1), found {value!r}")
            allow_zero = f.name in (
                "joint_floor_std_deg",
                "contact_release_mm",
                "clearance_mm",
                "precision_object_clearance_mm",
                "power_object_clearance_mm",
                "self_clearance_mm",
            )
            if not math.isfinite(value) or value < 0 or (value == 0 and not allow_zero):
                raise InputError(
                    f"{f.name}: expected a finite number {'>=' if allow_zero else '>'} 0, found {value!r}"
                )
            object.__setattr__(self, f.name, value)

    # -- derived quantities in SI ------------------------------------------------------------------------
    def modeling_stds(self, grasp_type: str) -> tuple[float, float, float]:
        """``(fingertip_std_m, wrist_position_std_m, wrist_rotation_std_rad)`` of Sigma_m for a grasp type."""
        return (
            self._of_grasp_type(grasp_type, "fingertip_std_mm") * 1e-3,
            self._of_grasp_type(grasp_type, "wrist_position_std_mm") * 1e-3,
            math.radians(self._of_grasp_type(grasp_type, "wrist_rotation_std_deg")),
        )

    def contact_steps(self, grasp_type: str) -> int:
        """The last steps that hold the demonstrated contacts (:mod:`inference.contact`) for a grasp type."""
        return int(self._of_grasp_type(grasp_type, "contact_steps"))

    def contact_release(self, grasp_type: str) -> str:
        """``sphere`` or ``step``: what a held sphere near the table or an obstacle releases."""
        return str(self._of_grasp_type(grasp_type, "contact_release"))

    def object_clearance_m(self, grasp_type: str) -> float:
        """The clearance of the hand's spheres from the grasped object [m] for a grasp type."""
        return self._of_grasp_type(grasp_type, "object_clearance_mm") * 1e-3

    def _of_grasp_type(self, grasp_type: str, name: str) -> float | str:
        """The field ``<grasp_type>_<name>``.

        Raises:
            InputError: ``grasp_type`` is neither ``precision`` nor ``power``.
        """
        if grasp_type not in ("precision", "power"):
            raise InputError(f"grasp_type: expected 'precision' or 'power', found {grasp_type!r}")
        return getattr(self, f"{grasp_type}_{name}")

    def smoothness_stds(self) -> np.ndarray:
        """The 19 stds of S_t, ``[omega (rad), v (m), joints (rad)]``, per trajectory step."""
        if self.smoothness_std_config is not None:
            return np.array(self.smoothness_std_config)
        return _config_stds(
            self.smooth_rotation_std_deg, self.smooth_position_std_mm, self.smooth_joint_std_deg
        )

    # -- I/O ---------------------------------------------------------------------------------------------
    def to_dict(self) -> dict:
        """A JSON/YAML-ready dict of every field (tuples as lists)."""
        out = dataclasses.asdict(self)
        for key in ("sigma_m_std_config", "smoothness_std_config"):
            if out[key] is not None:
                out[key] = list(out[key])
        return out

    @classmethod
    def from_dict(cls, data: dict | None, path=None) -> VariationParams:
        """Parameters from a mapping of field names; missing names keep their defaults.

        The former ``object_clearance_mm`` (one clearance for both grasp types) sets both
        ``precision_object_clearance_mm`` and ``power_object_clearance_mm``, so older files load unchanged.

        Raises:
            InputError: not a mapping, an unknown name, or an invalid value.
        """
        if data is None:
            return cls()
        if not isinstance(data, dict):
            raise InputError(
                f"parameters: expected a mapping of names to values, found {type(data).__name__}", path
            )
        if "object_clearance_mm" in data:  # the one object clearance of files written before 2026-12-04
            data = dict(data)
            value = data.pop("object_clearance_mm")
            for name in ("precision_object_clearance_mm", "power_object_clearance_mm"):
                data.setdefault(name, value)
        names = [f.name for f in dataclasses.fields(cls)]
        unknown = sorted(set(data) - set(names), key=str)
        if unknown:
            raise InputError(f"unknown parameters {unknown}; valid names: {', '.join(names)}", path)
        try:
            return cls(**data)
        except InputError as exc:
            raise InputError(exc.reason, path) from None

    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> VariationParams:
        """Load a YAML parameter file (see the module docstring).

        Raises:
            InputError: missing or unparsable file, unknown names, invalid values.
        """
        try:
            with open(path) as f:
                data = yaml.safe_load(f)
        except FileNotFoundError:
            raise InputError("no such parameter file", path) from None
        except IsADirectoryError:
            raise InputError("a directory, not a parameter file", path) from None
        except (yaml.YAMLError, UnicodeDecodeError) as exc:
            raise InputError(f"not valid YAML ({' '.join(str(exc).split())})", path) from None
        return cls.from_dict(data, path)


def _config_stds(rotation_deg: float, position_mm: float, joint_deg: float) -> np.ndarray:
    """19 stds ``[omega (rad) x 3, v (m) x 3, joints (rad) x 13]`` from a rotation, position and joint std."""
    rot, pos, joint = math.radians(rotation_deg), position_mm * 1e-3, math.radians(joint_deg)
    return np.array([rot] * 3 + [pos] * 3 + [joint] * 13)


def _is_numeric_seq(value) -> bool:
    try:
        np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        return False
    return not isinstance(value, (str, bytes))
