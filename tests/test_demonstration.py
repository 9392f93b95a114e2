"""The demonstration file format: round trip, and a clear InputError for each kind of bad file."""

import numpy as np
import pytest
import yaml

from assets import human_hand as hand
from assets.errors import InputError
from assets.se3 import se3_exp
from retarget.demonstration import Demonstration, default_object_prior


def make_demo(n=6, rng=None, **over):
    rng = rng or np.random.default_rng(0)
    lim = np.asarray(hand.JOINT_LIMITS, dtype=float)
    mu, cov = default_object_prior()
    T = se3_exp(rng.normal(size=(n, 6)) * 0.1)
    T[:, :3, 3] += [0.0, 0.0, 0.15]
    kw = dict(
        T_object_wrist=T,
        joints=rng.uniform(lim[:, 0], lim[:, 1], size=(n, 20)),
        t_s=np.arange(n) / 20.0,
        object="ham",
        grasp_type="precision",
        T_world_object_mean=mu,
        cov_object=cov,
        rate_hz=20.0,
        T_object_wrist_true=T,
        joints_true=np.clip(np.zeros((n, 20)), lim[:, 0], lim[:, 1]),
        contact_fingers=("thumb", "index"),
        strategy="test",
        noise={"glove_sigma_rad": 0.05},
        seed=3,
    )
    kw.update(over)
    return Demonstration(**kw)


def test_round_trip(tmp_path):
    demo = make_demo()
    path = demo.save(tmp_path / "d.npz")
    back = Demonstration.load(path)
    for key in ("T_object_wrist", "joints", "t_s", "T_world_object_mean", "cov_object", "joints_true"):
        np.testing.assert_array_equal(getattr(back, key), getattr(demo, key))
    assert (back.object, back.grasp_type, back.rate_hz, back.seed) == ("ham", "precision", 20.0, 3)
    assert back.contact_fingers == ("thumb", "index") and back.noise == {"glove_sigma_rad": 0.05}
    assert not list(tmp_path.glob(".*tmp"))
    q = back.q26(-1)
    assert q.shape == (26,)
    np.testing.assert_allclose(
        se3_exp(np.r_[q[3:6], 0, 0, 0])[:3, :3], demo.T_object_wrist[-1, :3, :3], atol=1e-12
    )


def test_optional_noise_free_keys(tmp_path):
    demo = make_demo(T_object_wrist_true=None, joints_true=None)
    back = Demonstration.load(demo.save(tmp_path / "d.npz"))
    assert back.joints_true is None
    with pytest.raises(InputError, match="noise-free"):
        back.q26(0, true=True)


def test_object_prior_is_the_papers():
    _, cov = default_object_prior()
    np.testing.assert_allclose(np.sqrt(np.diag(cov))[3:], 0.003)  # 3 mm: Sigma_o = 3^2 I mm^2
    np.testing.assert_allclose(np.degrees(np.sqrt(np.diag(cov))[:3]), 2.0)


@pytest.mark.parametrize(
    "field, value, match",
    [
        ("joints", np.full((6, 20), np.nan), "joints: non-finite"),
        ("joints", np.zeros((6, 19)), "joints: expected shape"),
        ("joints", np.full((6, 20), 60.0), "outside its limits"),  # degrees instead of radians
        ("t_s", np.arange(6) / 10.0, "t_s: expected times"),
        ("object", "teapot", "object: unknown object 'teapot'"),
        ("grasp_type", "pinch", "grasp_type"),
        ("cov_object", -np.eye(6), "cov_object: covariance is not positive definite"),
        ("contact_fingers", ("thumb", "pinky"), "contact_fingers: unknown fingers"),
        ("rate_hz", -20.0, "rate_hz"),
        ("T_object_wrist", np.tile(np.eye(4), (1, 1, 1)), "at least 2 steps"),
    ],
)
def test_validation(field, value, match):
    with pytest.raises(InputError, match=match):
        make_demo(**{field: value})


def test_millimetres_rejected():
    T = make_demo().T_object_wrist.copy()
    T[:, :3, 3] *= 1000.0
    with pytest.raises(InputError, match="metres"):
        make_demo(T_object_wrist=T)


def test_non_rotation_rejected():
    T = make_demo().T_object_wrist.copy()
    T[2, :3, :3] *= 1.1
    with pytest.raises(InputError, match="T_object_wrist: not a rotation"):
        make_demo(T_object_wrist=T)


def _rewrite(path, **changes):
    with np.load(path) as f:
        d = {k: f[k] for k in f.files}
    for k, v in changes.items():
        if v is None:
            d.pop(k)
        else:
            d[k] = v
    np.savez(path, **d)
    return path


def _header(path):
    with np.load(path) as f:
        return yaml.safe_load(str(f["header_yaml"]))


@pytest.mark.parametrize(
    "edit, match",
    [
        (lambda h: h.update(format="other"), "format: expected"),
        (lambda h: h.update(version=99), "version: expected 1"),
        (lambda h: h["joint_names"].__setitem__(3, "thumb_knuckle"), r"joint_names.*thumb_knuckle"),
        (lambda h: h.pop("object_prior"), "missing keys"),
        (lambda h: h["object_prior"].pop("cov_object"), "object_prior"),
        (lambda h: h.update(noise=[1, 2]), "noise: expected a mapping"),
    ],
)
def test_bad_header(tmp_path, edit, match):
    path = make_demo().save(tmp_path / "d.npz")
    h = _header(path)
    edit(h)
    _rewrite(path, header_yaml=np.str_(yaml.safe_dump(h)))
    with pytest.raises(InputError, match=match) as exc:
        Demonstration.load(path)
    assert str(path) in str(exc.value)  # the message names the file


def test_bad_files(tmp_path):
    path = make_demo().save(tmp_path / "d.npz")
    with pytest.raises(InputError, match="header_yaml: not valid YAML"):
        Demonstration.load(_rewrite(path, header_yaml=np.str_("a: [b")))
    path = make_demo().save(tmp_path / "e.npz")
    with pytest.raises(InputError, match=r"missing keys \['joints'\]"):
        Demonstration.load(_rewrite(path, joints=None))
    path = make_demo().save(tmp_path / "f.npz")
    path.write_bytes(path.read_bytes()[:200])
    with pytest.raises(InputError, match="npz"):
        Demonstration.load(path)
    with pytest.raises(InputError, match="no such"):
        Demonstration.load(tmp_path / "missing.npz")
    with pytest.raises(InputError, match="unknown demonstration"):
        Demonstration.load("teapot")


def test_first_and_last_steps_cut_every_per_step_array_alike():
    from retarget.demonstration import Demonstration

    demo = Demonstration.load("ham")
    head = demo.first_steps(5)
    assert head.num_steps == 5 and head.object == demo.object and head.rate_hz == demo.rate_hz
    for name in ("T_object_wrist", "joints", "t_s", "T_object_wrist_true", "joints_true"):
        np.testing.assert_array_equal(getattr(head, name), getattr(demo, name)[:5])
    np.testing.assert_array_equal(head.T_world_object_mean, demo.T_world_object_mean)
    assert demo.first_steps(demo.num_steps) is demo and demo.first_steps(10_000) is demo
    tail = demo.last_steps(5)
    assert tail.num_steps == 5 and tail.object == demo.object
    for name in ("T_object_wrist", "joints", "t_s", "T_object_wrist_true", "joints_true"):
        np.testing.assert_array_equal(getattr(tail, name), getattr(demo, name)[-5:])
    assert demo.last_steps(demo.num_steps) is demo
