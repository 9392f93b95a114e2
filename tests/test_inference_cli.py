"""``pbdgrasp infer``: writes a loadable model, refuses bad input with exit 2 and no file."""

import numpy as np
from test_inference_model import make_traj

from inference import VariationModel
from planning.cli import main


def test_infer_writes_a_model(tmp_path, capsys):
    traj = make_traj(n=6, seed=21)
    traj.save(tmp_path / "t.traj.npz")
    out = tmp_path / "m.model.npz"
    assert main(["infer", str(tmp_path / "t.traj.npz"), "-o", str(out)]) == 0
    assert "T = 6" in capsys.readouterr().out
    model = VariationModel.load(out)
    assert model.num_steps == 6 and model.iterations == 1
    np.testing.assert_array_equal(model.source.joints, traj.joints)


def test_infer_refuses_bad_input_without_writing(tmp_path, capsys):
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
