"""Keypoint import: the hand model fitted to 21 points a frame recovers the motion that made them.

Oracles: keypoints computed by the human hand's forward kinematics from each shipped demonstration's
noise-free motion fit back to its joints and wrist; a hand of another size gives back its scale and
segment lengths; with injected keypoint noise the measured noise is the injected one; the imported ham
retargets and infers like the shipped ham. Bad files go through the CLI (one line, exit status 2).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from assets import human_hand
from assets.errors import InputError
from assets.se3 import make_pose, so3_exp, so3_log
from pbdgrasp.cli import main
from retarget.demonstration import Demonstration
from retarget.keypoint_fit import KeypointFitConfig, _problem, calibrate_hand, fit_keypoints
from retarget.keypoints import (
    KEYPOINT_LINKS,
    KEYPOINT_NAMES,
    MODEL_SEGMENT_LENGTHS_M,
    SEGMENTS,
    KeypointRecording,
    keypoints_in_object,
    scaled_model,
    segment_vectors,
)

SHIPPED = ("ham", "jam", "small_cup", "chips", "salt")
#: Largest joint error of the fit of noise-free keypoints [deg] and of the wrist position [mm].
JOINT_TOL_DEG = 0.5
WRIST_TOL_MM = 1.0
#: Injected keypoint noise, per axis [m].
NOISE_M = 0.005
#: Relative tolerance of the measured keypoint noise against the injected one (its own spread: 1.5 %).
SIGMA_RTOL = 0.1
#: Fingertip RMSE of the imported ham's retargeting against the shipped ham's [mm] (issue 30).
RMSE_TOL_MM = 2.0


def true_keypoints(name: str, model=None) -> tuple[Demonstration, np.ndarray]:
    demo = Demonstration.load(name)
    return demo, keypoints_in_object(demo.T_object_wrist_true, demo.joints_true, model)


def test_the_layout_is_the_models_joint_centres():
    assert len(KEYPOINT_NAMES) == len(KEYPOINT_LINKS) == 21
    assert KEYPOINT_NAMES[:5] == ("wrist", "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip")
    assert KEYPOINT_NAMES[5:9] == ("index_mcp", "index_pip", "index_dip", "index_tip")
    assert set(KEYPOINT_LINKS) <= set(human_hand.model().link_names)
    joints = {j.child: j for j in human_hand.model().joints}
    for k, (a, b) in enumerate(SEGMENTS):  # the joint ending a segment carries its length
        assert np.linalg.norm(joints[KEYPOINT_LINKS[b]].T_parent_joint[:3, 3]) == pytest.approx(
            MODEL_SEGMENT_LENGTHS_M[k], abs=1e-15
        )
        assert KEYPOINT_NAMES[a].split("_")[0] == KEYPOINT_NAMES[b].split("_")[0]


def test_scaled_model_has_the_asked_sizes():
    lengths = MODEL_SEGMENT_LENGTHS_M * np.linspace(0.9, 1.2, 15)
    model = scaled_model(1.1, lengths)
    q = np.random.default_rng(0).uniform(*human_hand.JOINT_LIMITS.T, size=(4, 20))
    k = keypoints_in_object(np.broadcast_to(np.eye(4), (4, 4, 4)), q, model)
    np.testing.assert_allclose(np.linalg.norm(segment_vectors(k), axis=-1), np.broadcast_to(lengths, (4, 15)))
    k0 = keypoints_in_object(np.broadcast_to(np.eye(4), (4, 4, 4)), q)
    np.testing.assert_allclose(k[:, [1, 5, 9, 13, 17]], 1.1 * k0[:, [1, 5, 9, 13, 17]], atol=1e-15)


def test_the_jacobian_is_the_numerical_one():
    """The smoothed problem's sparse analytic Jacobian against central differences, rotations off zero."""
    demo, y = true_keypoints("chips")
    y = y[28:33]
    rng = np.random.default_rng(3)
    R_ref = demo.T_object_wrist_true[28:33, :3, :3]
    x = np.concatenate(
        [rng.normal(scale=0.3, size=(5, 3)), rng.normal(scale=0.1, size=(5, 3)), demo.joints_true[28:33]], 1
    )
    fun, jac = _problem(scaled_model(1.05), y, R_ref, 0.004, 0.05, KeypointFitConfig(), smooth=True)
    v, h = x.ravel(), 1e-6
    numeric = np.stack([(fun(v + h * e) - fun(v - h * e)) / (2 * h) for e in np.eye(v.size)], axis=1)
    analytic = jac(v).toarray()
    assert analytic.shape == numeric.shape == (5 * 63 + 3 * 32, 5 * 26)
    np.testing.assert_allclose(analytic, numeric, atol=1e-5 * np.abs(numeric).max())


def test_config_is_validated():
    with pytest.raises(InputError, match="joint_accel_sigma_rad_s2: expected a finite number > 0"):
        KeypointFitConfig(joint_accel_sigma_rad_s2=0.0)
    with pytest.raises(InputError, match="max_nfev"):
        KeypointFitConfig(max_nfev="many")


@pytest.mark.parametrize("name", SHIPPED)
def test_true_keypoints_fit_back_to_the_true_motion(name):
    demo, y = true_keypoints(name)
    fit = fit_keypoints(y, demo.rate_hz)
    assert fit.success, fit.message
    joint_err_deg = np.degrees(np.abs(fit.joints - demo.joints_true)).max()
    wrist_err_mm = 1e3 * np.linalg.norm(
        fit.T_object_wrist[:, :3, 3] - demo.T_object_wrist_true[:, :3, 3], axis=-1
    )
    R_err = np.swapaxes(demo.T_object_wrist_true[:, :3, :3], 1, 2) @ fit.T_object_wrist[:, :3, :3]
    assert joint_err_deg < JOINT_TOL_DEG, f"joints {joint_err_deg:.4f} deg off"
    assert wrist_err_mm.max() < WRIST_TOL_MM, f"wrist {wrist_err_mm.max():.4f} mm off"
    assert np.degrees(np.linalg.norm(so3_log(R_err), axis=-1)).max() < JOINT_TOL_DEG
    assert np.all(fit.joints >= human_hand.JOINT_LIMITS[:, 0]) and np.all(
        fit.joints <= human_hand.JOINT_LIMITS[:, 1]
    )
    assert fit.residual_max_m.max() < 1e-6
    assert abs(fit.calibration.scale - 1.0) < 1e-9
    np.testing.assert_allclose(fit.calibration.segment_lengths_m, MODEL_SEGMENT_LENGTHS_M, atol=1e-9)


def test_another_hand_size_is_measured():
    """A hand 8 % larger with longer index and shorter little fingers: the fit finds its size."""
    lengths = 1.08 * MODEL_SEGMENT_LENGTHS_M
    lengths[3:6] *= 1.1  # index
    lengths[12:15] *= 0.9  # little
    demo, y = true_keypoints("jam", scaled_model(1.08, lengths))
    fit = fit_keypoints(y, demo.rate_hz)
    assert abs(fit.calibration.scale - 1.08) < 1e-9
    np.testing.assert_allclose(fit.calibration.segment_lengths_m, lengths, atol=1e-9)
    assert np.degrees(np.abs(fit.joints - demo.joints_true)).max() < JOINT_TOL_DEG


def test_the_measured_noise_is_the_injected_one():
    demo, y = true_keypoints("chips")
    y = y + np.random.default_rng(0).normal(scale=NOISE_M, size=y.shape)
    fit = fit_keypoints(y, demo.rate_hz)
    assert abs(fit.sigma_m / NOISE_M - 1.0) < SIGMA_RTOL, f"sigma {fit.sigma_m * 1e3:.2f} mm"
    # per frame RMS of the final fit: between the unsmoothed fit's sqrt((63 - 26) / 63) and the noise
    median_mm = 1e3 * np.median(fit.residual_rms_m)
    assert np.sqrt(37 / 63) * NOISE_M * 1e3 * 0.95 < median_mm < NOISE_M * 1e3, median_mm
    # the segments' standard errors are honest: every length within 3.5 of them (15 segments)
    err = np.abs(fit.calibration.segment_lengths_m - MODEL_SEGMENT_LENGTHS_M)
    assert np.all(err < 3.5 * fit.calibration.segment_length_se_m), (err, fit.calibration.segment_length_se_m)
    # the smoothness halves the per-frame fit's joint error (13.5 deg RMS measured for the ham)
    assert np.sqrt(np.mean(np.degrees(fit.joints - demo.joints_true) ** 2)) < 8.0


def test_calibration_corrects_the_noise_bias_of_segment_lengths():
    _, y = true_keypoints("salt")
    y = y + np.random.default_rng(1).normal(scale=NOISE_M, size=y.shape)
    cal = calibrate_hand(y, length_prior_rel_sigma=1e6)  # the data alone
    naive = np.linalg.norm(segment_vectors(y), axis=-1).mean(0)
    assert (
        np.abs(cal.segment_lengths_m - MODEL_SEGMENT_LENGTHS_M).mean()
        < 0.5 * np.abs(naive - MODEL_SEGMENT_LENGTHS_M).mean()
    )


def test_resampling_is_linear_in_time():
    t = np.array([0.0, 0.03, 0.1, 0.16])
    p = np.broadcast_to((0.2 + 3.0 * t)[:, None, None], (4, 21, 3))
    out = KeypointRecording(p, t, 25.0).resampled(20.0)
    np.testing.assert_allclose(out[:, 0, 0], 0.2 + 3.0 * np.arange(4) / 20.0)


def test_cli_imports_a_camera_frame_recording(tmp_path, capsys):
    """Points in a moving camera frame with time stamps that start late: the demonstration is the same."""
    demo, y = true_keypoints("small_cup")
    n = demo.num_steps
    rng = np.random.default_rng(2)
    T_frame_object = make_pose(
        so3_exp(rng.normal(size=3)) @ so3_exp(np.linspace(0, 0.3, n)[:, None] * [0, 0, 1]), [0.1, -0.2, 0.6]
    )
    p_frame = np.einsum("tij,tkj->tki", T_frame_object[:, :3, :3], y) + T_frame_object[:, None, :3, 3]
    src = tmp_path / "cup.keypoints.npz"
    np.savez(
        src, keypoints=p_frame, rate_hz=20.0, t_s=12.5 + np.arange(n) / 20.0, T_frame_object=T_frame_object
    )
    out = tmp_path / "cup.npz"
    assert main(["demo", "import", str(src), "--object", "small_cup", "-o", str(out)]) == 0
    assert "small_cup: 61 steps" in capsys.readouterr().out
    back = Demonstration.load(out)
    assert (back.object, back.grasp_type, back.num_steps, back.rate_hz) == ("small_cup", "precision", n, 20.0)
    assert back.joints_true is None and back.hand["scale"] == pytest.approx(1.0)
    assert len(back.noise["keypoint_residual_rms_m"]) == n and back.noise["keypoint_sigma_m"] < 1e-6
    assert np.degrees(np.abs(back.joints - demo.joints_true)).max() < JOINT_TOL_DEG
    assert (
        1e3 * np.abs(back.T_object_wrist[:, :3, 3] - demo.T_object_wrist_true[:, :3, 3]).max() < WRIST_TOL_MM
    )
    assert (
        main(["demo", "import", str(src), "--object", "chips", "--grasp-type", "precision", "-o", str(out)])
        == 0
    )
    assert Demonstration.load(out).grasp_type == "precision"


def test_imported_ham_retargets_and_infers_like_the_shipped_one(tmp_path, capsys):
    from inference.model import VariationModel
    from retarget.trajectory import Trajectory

    _, y = true_keypoints("ham")
    src = tmp_path / "ham.keypoints.npz"
    np.savez(src, keypoints=y + np.random.default_rng(0).normal(scale=NOISE_M, size=y.shape), rate_hz=20.0)
    assert main(["demo", "import", str(src), "--object", "ham", "-o", str(tmp_path / "ham.npz")]) == 0
    runs = {}
    for label, demo in (("shipped", "ham"), ("imported", str(tmp_path / "ham.npz"))):
        traj, model = tmp_path / f"{label}.traj.npz", tmp_path / f"{label}.model.npz"
        assert main(["retarget", demo, "-o", str(traj), "--no-collision", "--no-progress"]) == 0
        assert main(["infer", str(traj), "-o", str(model)]) == 0
        runs[label] = Trajectory.load(traj), VariationModel.load(model)
    (t_s, m_s), (t_i, m_i) = runs["shipped"], runs["imported"]
    assert t_i.grasp_type == t_s.grasp_type == m_i.grasp_type == m_s.grasp_type == "precision"
    assert abs(t_i.meta["rmse_mm"] - t_s.meta["rmse_mm"]) < RMSE_TOL_MM, (
        t_i.meta["rmse_mm"],
        t_s.meta["rmse_mm"],
    )
    assert t_i.meta["virtual_fingers"]["groups"] == t_s.meta["virtual_fingers"]["groups"]
    assert m_i.converged and m_s.converged


# -- bad files ----------------------------------------------------------------------------------------
def _good() -> dict:
    _, y = true_keypoints("jam")
    return {"keypoints": y[:8], "rate_hz": np.array(20.0)}


def _edit(**changes):
    def make():
        d = _good()
        d.update(changes)
        return {k: v for k, v in d.items() if v is not None}

    return make


def _nan():
    d = _good()
    d["keypoints"][3, 7, 1] = np.nan
    return d


def _swapped_times():
    d = _good()
    d["t_s"] = np.array([0.0, 0.05, 0.15, 0.1, 0.2, 0.25, 0.3, 0.35])
    return d


def _scaled(factor, centred=False):
    def make():
        d = _good()
        k = d["keypoints"]
        d["keypoints"] = factor * (k - k[:, :1]) if centred else factor * k
        return d

    return make


def _order(perm):
    def make():
        d = _good()
        d["keypoints"] = d["keypoints"][:, perm]
        return d

    return make


def _left_hand():
    """The whole jam demonstration mirrored (its first frames hold the fingers open: no handedness)."""
    return {"keypoints": true_keypoints("jam")[1] * [1.0, -1.0, 1.0], "rate_hz": np.array(20.0)}


_MANO_ORDER = [0, 5, 6, 7, 9, 10, 11, 17, 18, 19, 13, 14, 15, 1, 2, 3, 4, 8, 12, 16, 20]
BAD = {
    "wrong_shape": (_edit(keypoints=np.zeros((8, 20, 3))), r"keypoints: expected shape \(N, 21, 3\)"),
    "flat": (_edit(keypoints=np.zeros((8, 63))), r"keypoints: expected shape"),
    "nan": (_nan, r"keypoints: non-finite value at index \(3, 7, 1\)"),
    "one_frame": (lambda: {**_good(), "keypoints": _good()["keypoints"][:1]}, r"at least 2 frames"),
    "missing_rate": (_edit(rate_hz=None), r"missing keys \['rate_hz'\]"),
    "rate_negative": (_edit(rate_hz=np.array(-20.0)), r"rate_hz: must be a positive"),
    "rate_text": (_edit(rate_hz=np.array("fast")), r"rate_hz: expected"),
    "typo_key": (_edit(T_object_frame=np.eye(4)), r"unknown keys \['T_object_frame'\]"),
    "out_of_order": (_swapped_times, r"t_s: frames out of order: frame 3 at 0.1 s"),
    "camera_not_rigid": (
        _edit(T_frame_object=np.tile(np.diag([1.0, 2.0, 1.0, 1.0]), (8, 1, 1))),
        r"T_frame_object: not a rotation",
    ),
    "camera_missing": (
        _edit(keypoints=_good()["keypoints"] + [0.3, 0.2, 1.5]),
        r"wrist .* more than 1.0 m.*T_frame_object",
    ),
    "millimetres": (_scaled(1000.0), r"wrist .* from the object .*millimetres\?"),
    "millimetres_at_origin": (
        _scaled(1000.0, centred=True),
        r"the palm is 1000 times the model's.*millimetres",
    ),
    "mano_order": (
        _order(_MANO_ORDER),
        r"fit the model's palm .* expected the 21 points in the order wrist, thumb_cmc",
    ),
    "left_hand": (_left_hand, r"fingers bend backwards by 1\d deg on average.*a left hand"),
}


@pytest.mark.parametrize("name", sorted(BAD))
def test_bad_file_gives_exit_2_and_one_line_naming_the_file(name, tmp_path, capsys):
    make, expect = BAD[name]
    path = tmp_path / f"{name}.npz"
    np.savez(path, **make())
    out = tmp_path / "out" / "demo.npz"
    out.parent.mkdir()
    status = main(["demo", "import", str(path), "--object", "jam", "-o", str(out)])
    lines = capsys.readouterr().err.strip().splitlines()
    assert status == 2 and len(lines) == 1, lines
    assert lines[0].startswith(f"error: {path}: "), lines[0]
    assert re.search(expect, lines[0]), (expect, lines[0])
    assert not list(out.parent.iterdir())


def test_a_pickle_is_refused(tmp_path, capsys):
    path = tmp_path / "pickled.npz"
    np.savez(path, keypoints=np.array([{"keypoints": 1}], dtype=object), rate_hz=20.0)
    assert main(["demo", "import", str(path), "--object", "jam", "-o", str(tmp_path / "d.npz")]) == 2
    assert re.search(r"not a readable \.npz.*pickle", capsys.readouterr().err, re.IGNORECASE)


@pytest.mark.parametrize(
    "argv, expect",
    [
        (["--object", "teapot"], r"--object: unknown object 'teapot'; valid names: .*jam"),
        (["--object", "jam", "--rate-hz", "0"], r"--rate-hz: expected a number in \[1, 1000\] Hz"),
        (["--object", "jam", "--grasp-type", "pinch"], r"invalid choice: 'pinch'"),
    ],
)
def test_bad_arguments(argv, expect, tmp_path, capsys):
    src = tmp_path / "k.npz"
    np.savez(src, **_good())
    assert main(["demo", "import", str(src), *argv, "-o", str(tmp_path / "d.npz")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and re.search(expect, err[0]), err
    assert not (tmp_path / "d.npz").exists()
