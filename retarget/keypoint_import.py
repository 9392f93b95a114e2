"""``pbdgrasp demo import``: a keypoint file to a human demonstration (``assets/demonstrations`` format).

The file is described in :mod:`retarget.keypoints`, the fit in :mod:`retarget.keypoint_fit`. The points
are resampled linearly to the demonstration's rate, the hand model fitted, and the demonstration written
with the fitted motion, the measured residuals as its noise model and the fitted hand under ``hand``.
"""

from __future__ import annotations

import logging
from dataclasses import asdict
from pathlib import Path

import numpy as np

import assets
from assets.errors import InputError

from .demonstration import GRASP_TYPES, RATE_HZ, Demonstration, default_object_prior
from .keypoint_fit import KeypointFit, KeypointFitConfig, fit_keypoints
from .keypoints import load_keypoints

__all__ = ["import_keypoints"]

log = logging.getLogger(__name__)


def import_keypoints(
    path: str | Path,
    object_name: str,
    grasp_type: str | None = None,
    rate_hz: float = RATE_HZ,
    config: KeypointFitConfig | None = None,
) -> tuple[Demonstration, KeypointFit]:
    """A keypoint file to a :class:`~retarget.demonstration.Demonstration` of ``object_name`` at ``rate_hz``.

    Args:
        path: the ``.npz`` keypoint file (:func:`load_keypoints`).
        object_name: the grasped object, one of ``assets.objects()``.
        grasp_type: ``"precision"`` or ``"power"``; default the object's (``object.yaml``).
        rate_hz: the demonstration's rate; the points are resampled to it (linear interpolation).
        config: the fit's settings.

    Returns:
        The demonstration (object prior :func:`default_object_prior`, no noise-free keys, the measured
        noise under ``noise`` and the hand under ``hand``) and the fit.

    Raises:
        InputError: a bad file, object, grasp type or rate, or a fit that cannot explain the points.
    """
    if object_name not in assets.objects():
        raise InputError(
            f"--object: unknown object {object_name!r}; valid names: {', '.join(assets.objects())}"
        )
    grasp_type = grasp_type or assets.object_metadata(object_name)["grasp_type"]
    if grasp_type not in GRASP_TYPES:
        raise InputError(f"--grasp-type: expected one of {GRASP_TYPES}, found {grasp_type!r}")
    if not (np.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate-hz: expected a positive number of Hz, found {rate_hz}")
    rec = load_keypoints(path)
    y = rec.resampled(rate_hz)
    if len(y) < 2:
        raise InputError(f"keypoints: {rec.t_s[-1]:.3g} s is shorter than one step at {rate_hz} Hz", path)
    fit = fit_keypoints(y, rate_hz, config, path)
    if not fit.success:
        log.warning("%s: the smoothed fit did not converge: %s", path, fit.message)
    mu, cov = default_object_prior()
    noise = {
        "model": "measured: residuals of the hand model fitted to 21 keypoints (retarget/keypoint_fit.py)",
        "keypoint_sigma_m": fit.sigma_m,
        "keypoint_residual_rms_m": np.round(fit.residual_rms_m, 7).tolist(),
        "keypoint_residual_max_m": np.round(fit.residual_max_m, 7).tolist(),
        "residuals": "per frame of the smoothed fit: RMS over the 63 coordinates, largest point distance",
        "tracker_position_sigma_m": float(np.mean(fit.frame_std["position_m"])),
        "tracker_rotation_sigma_rad": float(np.mean(fit.frame_std["rotation_rad"])),
        "glove_sigma_rad": float(np.mean(fit.frame_std["joints_rad"])),
        "sigmas": "of one frame's fit before smoothing (keypoint_sigma_m propagated), medians over frames",
        "smoothness": {k: v for k, v in asdict(config or KeypointFitConfig()).items() if "accel" in k},
    }
    demo = Demonstration(
        T_object_wrist=fit.T_object_wrist,
        joints=fit.joints,
        t_s=np.arange(len(y)) / rate_hz,
        object=object_name,
        grasp_type=grasp_type,
        T_world_object_mean=mu,
        cov_object=cov,
        rate_hz=rate_hz,
        strategy=f"imported from the keypoints {Path(path).name} ({rec.rate_hz:g} Hz, {len(rec.t_s)} frames)",
        noise=noise,
        hand={**fit.calibration.header(), "fit_nfev": fit.nfev, "fit_converged": fit.success},
    )
    return demo, fit
