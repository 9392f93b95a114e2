"""Pictures of a pybullet world: the default camera of a scene and pybullet's TinyRenderer (no display)."""

from __future__ import annotations

import numpy as np

import assets
from assets.errors import InputError

from ._pybullet import pb
from .scene import Scene

__all__ = ["default_camera", "render_image"]


def default_camera(scene: Scene, view: str = "side") -> dict:
    """Camera parameters looking at the target object: ``eye``, ``target``, ``up`` (world, m), ``fov_deg``.

    Args:
        scene: the scene.
        view: ``side`` (from the front-right, 30 deg above the table) or ``top`` (from above).
    """
    meta = assets.object_metadata(scene.object.name)
    bb = meta["bounding_box_m"]
    centre_object = (np.array(bb["min"]) + np.array(bb["max"])) / 2
    target = (scene.T_world_object @ np.append(centre_object, 1.0))[:3]
    target[2] = max(target[2], 0.06)
    if view == "top":
        return {"eye": target + [0.0, -0.02, 1.1], "target": target, "up": [0.0, 1.0, 0.0], "fov_deg": 45.0}
    if view != "side":
        raise InputError(f"unknown camera view {view!r}; valid: side, top")
    d, az, el = 1.05, np.radians(-35.0), np.radians(30.0)
    eye = target + d * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    return {"eye": eye, "target": target + [0, 0, 0.12], "up": [0.0, 0.0, 1.0], "fov_deg": 45.0}


def render_image(client: int, cam: dict, width: int = 640, height: int = 480) -> np.ndarray:
    """An RGB picture (height, width, 3) uint8 of pybullet client ``client`` seen by camera ``cam``
    (:func:`default_camera`'s keys), by pybullet's TinyRenderer."""
    view = pb.computeViewMatrix(
        list(map(float, cam["eye"])),
        list(map(float, cam["target"])),
        list(map(float, cam["up"])),
        physicsClientId=client,
    )
    proj = pb.computeProjectionMatrixFOV(cam["fov_deg"], width / height, 0.02, 5.0, physicsClientId=client)
    img = pb.getCameraImage(
        width,
        height,
        view,
        proj,
        renderer=pb.ER_TINY_RENDERER,
        lightDirection=[0.4, -0.6, 1.0],
        shadow=0,
        physicsClientId=client,
    )
    rgba = np.reshape(np.asarray(img[2], dtype=np.uint8), (height, width, 4))
    return rgba[:, :, :3].copy()
