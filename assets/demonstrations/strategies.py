"""The grasping strategies of the five synthetic demonstrations (the paper's section VIII, Fig. 5-7):
where the human fingertips land on each object, how the wrist is turned, and from where the hand comes.
Positions in metres in the object frame; orientations as ``R_object_wrist`` (the wrist's x axis is the
palm normal, y points to the thumb side).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Strategy", "STRATEGIES", "DEMONSTRATED_OBJECTS"]


def _frame(x_w, y_w) -> np.ndarray:
    """R_object_wrist from the wrist's x (palm normal) and y (thumb side) axes in the object frame."""
    x = np.asarray(x_w, float) / np.linalg.norm(x_w)
    y = np.asarray(y_w, float) - np.dot(y_w, x) * x
    y /= np.linalg.norm(y)
    return np.column_stack([x, y, np.cross(x, y)])


def _cyl(radius: float, phi_deg: float, z: float) -> tuple[float, float, float]:
    phi = np.deg2rad(phi_deg)
    return (radius * np.cos(phi), radius * np.sin(phi), z)


@dataclass(frozen=True)
class Strategy:
    """A grasping strategy: where the fingers go and how the hand comes in.

    Attributes:
        object: object name.
        grasp_type: ``"precision"`` or ``"power"``.
        description: one line for the file header.
        R_object_wrist: (3, 3) preferred final wrist orientation.
        p_object_wrist: (3,) initial guess of the final wrist position [m].
        targets: finger -> a point near the surface where its fingertip should land [m, object frame].
        approach: (3,) direction from the grasp towards the pre-grasp (object frame).
        palm_gap_m: for power grasps, the wanted distance of the palm samples' surface to the object.
        standoff_m: fingertip stand-off of the fit before closing.
        duration_s: length of the demonstration.
        orientation_sigma_rad: how strongly the fit keeps the preferred orientation.
    """

    object: str
    grasp_type: str
    description: str
    R_object_wrist: np.ndarray
    p_object_wrist: np.ndarray
    targets: dict
    approach: np.ndarray
    palm_gap_m: float | None = None
    standoff_m: float = 0.006
    duration_s: float = 3.0
    orientation_sigma_rad: float = float(np.deg2rad(15.0))


def _strategies() -> dict[str, Strategy]:
    down = (0.0, 0.0, -1.0)
    S = {}
    # Ham can (10 x 5.5 x 8 cm): straight from above, palm down, fingers close to the tin; thumb on the
    # +y face, index and little on the rounded vertical edges, middle and ring on the flat -y face, all
    # at about mid-height (contacts near the top edge let the SAH's closing fingers slip over it).
    S["ham"] = Strategy(
        "ham",
        "precision",
        "straight from above, fingers close to the can: thumb on one long side, index and little on the "
        "rounded corners, middle and ring on the opposite long side, at about mid-height",
        _frame(down, (1.0, 0.0, 0.0)),
        np.array([0.0, 0.055, 0.13]),
        {
            "thumb": (0.0, 0.03, 0.045),
            "index": (0.045, -0.026, 0.045),
            "middle": (0.012, -0.03, 0.042),
            "ring": (-0.013, -0.03, 0.042),
            "little": (-0.045, -0.026, 0.047),
        },
        np.array([0.0, 0.0, 1.0]),
    )
    # Jam jar (7 cm diameter, 9 cm high): from above, fingertips around the jar's body below the lid;
    # ring and little close together.
    S["jam"] = Strategy(
        "jam",
        "precision",
        "from above, fingertips around the jar below the lid: thumb opposite the four fingers, ring and "
        "little close together",
        _frame(down, (0.0, -1.0, 0.0)),
        np.array([0.06, 0.0, 0.18]),
        {
            "thumb": _cyl(0.037, 5, 0.055),
            "index": _cyl(0.037, 235, 0.055),
            "middle": _cyl(0.037, 195, 0.055),
            "ring": _cyl(0.037, 158, 0.055),
            "little": _cyl(0.037, 136, 0.055),
        },
        np.array([0.0, 0.0, 1.0]),
    )
    # Small cup (8 cm diameter, handle at +x): by its body from above, away from the handle.
    S["small_cup"] = Strategy(
        "small_cup",
        "precision",
        "by its body from above, away from the handle: thumb on the +y side, fingers around the -y side",
        # The thumb side towards +y (tilted 17 deg away from the handle). With it towards +x, as before,
        # the fit put the thumb on the handle side with a normal 31-81 deg from the fingers': no opposition.
        _frame(down, (-0.3, 1.0, 0.0)),
        np.array([0.0, 0.0, 0.17]),
        {
            "thumb": _cyl(0.042, 95, 0.055),
            "index": _cyl(0.042, 325, 0.055),
            "middle": _cyl(0.042, 285, 0.055),
            "ring": _cyl(0.042, 248, 0.055),
            "little": _cyl(0.042, 226, 0.055),
        },
        np.array([0.0, 0.0, 1.0]),
    )
    # Chips can (7.5 cm diameter, 23 cm high): a cylindrical power grasp from the side, thumb up. The palm
    # lies on the -x side; the fingers wrap round the -y side towards +x, the thumb round the +y side the
    # other way, above the index, so that its contact opposes theirs (136 deg from their mean normal).
    side = np.array([-1.0, 0.0, 0.0])
    S["chips"] = Strategy(
        "chips",
        "power",
        "wrapped from the side, thumb up: palm on the can, fingers round one side, thumb round the other",
        _frame((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        np.array([-0.054, 0.07, 0.11]),
        {
            "thumb": _cyl(0.039, 70, 0.17),
            "index": _cyl(0.039, 315, 0.14),
            "middle": _cyl(0.039, 330, 0.12),
            "ring": _cyl(0.039, 318, 0.10),
            "little": _cyl(0.039, 315, 0.08),
        },
        side,
        palm_gap_m=0.002,
    )
    # Salt box (9 x 6 x 14 cm): power grasp from the side, thumb up, palm on the narrow -x face, the
    # fingers round its edge onto the -y face, the thumb round the other edge onto the +y face.
    S["salt"] = Strategy(
        "salt",
        "power",
        "from the side, thumb up: palm on the narrow face, fingers wrapped onto one wide face, thumb on the "
        "other",
        _frame((1.0, 0.0, 0.0), (0.0, 0.0, 1.0)),
        np.array([-0.063, 0.062, 0.06]),
        {
            "thumb": (-0.008, 0.032, 0.11),
            "index": (0.01, -0.032, 0.09),
            "middle": (0.02, -0.032, 0.075),
            "ring": (0.01, -0.032, 0.055),
            "little": (0.0, -0.032, 0.04),
        },
        side,
        palm_gap_m=0.002,
    )
    return S


STRATEGIES: dict[str, Strategy] = _strategies()
DEMONSTRATED_OBJECTS = tuple(STRATEGIES)
