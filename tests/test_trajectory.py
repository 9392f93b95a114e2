"""The .traj.npz contract: round trip and validation."""

import numpy as np
import pytest

from assets.errors import InputError
from assets.se3 import se3_exp
from retarget.trajectory import Trajectory


def make_traj(n=5, rng=None):
    rng = rng or np.random.default_rng(0)
    A = rng.normal(size=(n, 19, 4))
    return Trajectory(
        T_object_wrist=se3_exp(rng.normal(size=(n, 6)) * 0.1),
        joints=rng.uniform(0, 1, size=(n, 13)),
        cov_retarget=A @ np.swapaxes(A, 1, 2) * 1e-6,
        fingertip_rmse_mm=np.full(n, 7.0),
        T_world_object_mean=np.eye(4),
        cov_object=np.diag([1e-3] * 3 + [9e-6] * 3),
        dt_s=0.05,
        object="ham",
        grasp_type="precision",
        meta={"demo": "ham"},
    )


def test_round_trip(tmp_path):
    tr = make_traj()
    path = tr.save(tmp_path / "x.traj.npz")
    back = Trajectory.load(path)
    for key in ("T_object_wrist", "joints", "cov_retarget", "fingertip_rmse_mm", "cov_object"):
        np.testing.assert_array_equal(getattr(back, key), getattr(tr, key))
    assert (back.object, back.grasp_type, back.dt_s, back.meta) == ("ham", "precision", 0.05, {"demo": "ham"})
    assert not list(tmp_path.glob(".*tmp"))


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("joints", np.full((5, 13), np.nan), "non-finite"),
        ("joints", np.zeros((5, 12)), "expected shape"),
        ("cov_object", -np.eye(6), "positive definite"),
        ("grasp_type", "pinch", "grasp_type"),
        ("dt_s", -1.0, "positive"),
    ],
)
def test_validation(field, value, match):
    tr = make_traj()
    kwargs = {k: getattr(tr, k) for k in tr.__dataclass_fields__}
    kwargs[field] = value
    with pytest.raises(InputError, match=match):
        Trajectory(**kwargs)


def test_non_rotation_rejected():
    tr = make_traj()
    T = tr.T_object_wrist.copy()
    T[0, :3, :3] *= 1.1
    kwargs = {k: getattr(tr, k) for k in tr.__dataclass_fields__}
    kwargs["T_object_wrist"] = T
    with pytest.raises(InputError, match="rotation"):
        Trajectory(**kwargs)


def test_truncated_file(tmp_path):
    path = make_traj().save(tmp_path / "x.traj.npz")
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    with pytest.raises(InputError, match="npz"):
        Trajectory.load(path)


def test_atomic_write_gives_an_ordinary_file_mode(tmp_path):
    import os

    path = make_traj().save(tmp_path / "m.traj.npz")
    umask = os.umask(0)
    os.umask(umask)
    assert path.stat().st_mode & 0o777 == 0o666 & ~umask
