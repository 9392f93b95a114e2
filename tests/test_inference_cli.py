"""``pbdgrasp infer``: writes a loadable model, refuses bad input with exit 2 and no file."""

import numpy as np

from assets.sah import JOINT_LIMITS
from inference import VariationModel, solve
from pbdgrasp.cli import main


def test_infer_writes_a_model(make_traj, tmp_path, capsys):
    traj = make_traj(n=6, seed=21)
    traj.save(tmp_path / "t.traj.npz")
    out = tmp_path / "m.model.npz"
    assert main(["infer", str(tmp_path / "t.traj.npz"), "-o", str(out)]) == 0
    assert "T = 6" in capsys.readouterr().out
    model = VariationModel.load(out)
    assert model.num_steps == 6 and model.converged
    np.testing.assert_array_equal(model.source.joints, traj.joints)
    # the CLI holds the SAH's joint limits: this synthetic tau_r leaves them by up to 24 deg, a model without
    # the limits by 11.5 deg; the CLI's means stay inside them
    lo, hi = JOINT_LIMITS[:, 0], JOINT_LIMITS[:, 1]
    beyond = lambda j: np.degrees(np.maximum(lo - j, j - hi).max())  # noqa: E731
    assert beyond(traj.joints) > 20 and beyond(solve(traj).joints_mean) > 10
    assert beyond(model.joints_mean) < 0


def test_infer_refuses_bad_input_without_writing(make_traj, tmp_path, capsys):
    raw = dict(np.load(make_traj(n=3, seed=22).save(tmp_path / "t.traj.npz")))
    raw["cov_retarget"][1, 0, 0] = np.nan
    np.savez(tmp_path / "bad.traj.npz", **raw)
    (tmp_path / "p.yaml").write_text("no_such_parameter: 1\n")
    out = tmp_path / "m.model.npz"
    assert main(["infer", str(tmp_path / "bad.traj.npz"), "-o", str(out)]) == 2
    assert "non-finite" in capsys.readouterr().err
    assert (
        main(["infer", str(tmp_path / "t.traj.npz"), "--params", str(tmp_path / "p.yaml"), "-o", str(out)])
        == 2
    )
    assert "unknown parameters" in capsys.readouterr().err
    assert not out.exists()
