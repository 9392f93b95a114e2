"""The final grasp chosen again in a scene (pbdgrasp.scene_grasp): which candidates are solved again, which
model is kept, and where the blend puts tau_r's last step. The closing, the solve and the measurement are
stand-ins whose answers are set by the test, so the selection rule is checked against the answer worked
out by hand; the real pieces have their own tests."""

from __future__ import annotations

import dataclasses
import types

import numpy as np
import pytest

import pbdgrasp.scene_grasp as sg
from assets import sah
from assets.errors import InputError
from assets.se3 import se3_exp

T_STEPS = 30


@dataclasses.dataclass(frozen=True)
class FakeTrajectory:
    T_object_wrist: np.ndarray
    joints: np.ndarray
    meta: dict
    path: str | None = None


@dataclasses.dataclass(frozen=True)
class FakeModel:
    T_object_wrist_mean: np.ndarray
    joints_mean: np.ndarray
    cov: np.ndarray
    source: FakeTrajectory | None
    label: str = "original"


def _model(source=True) -> FakeModel:
    rng = np.random.default_rng(0)
    T = np.stack([se3_exp(np.r_[rng.normal(size=3) * 0.1, 0.01 * k, 0.0, 0.2]) for k in range(T_STEPS)])
    J = np.tile(sah.rest_joints(), (T_STEPS, 1))
    traj = FakeTrajectory(T, J, {"scene": "demo"}) if source else None
    # the model's last mean: tau_r's last step moved by the clearances (a turn and 12 mm)
    T_mean = T.copy()
    T_mean[-1] = T[-1] @ se3_exp(np.r_[0.02, -0.01, 0.03, 0.012, 0.0, -0.004])
    J_mean = J.copy()
    J_mean[-1] = sah.clip_joints(J[-1] + 0.05)
    return FakeModel(T_mean, J_mean, np.tile(np.eye(19) * 1e-4, (T_STEPS, 1, 1)), traj)


class FakePool:
    def __init__(self, *args, **kwargs):
        pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        return False


def _install(monkeypatch, probe_q, scores, measures):
    """Stand-ins: probe draw i closes to ``probe_q[i]`` and sits 1 mm x i from the mean with joint 0 at
    i / 100; a candidate scores ``scores[key]`` (key: -1 for the mean, else its probe draw's i); a model
    measures ``measures[its label]``. Returns the trajectories handed to the solve."""
    solved = []

    class FakeExpected:
        def __init__(self, closer, T_world_object, cov_object, cov, n, rng, offset=None):
            self.n = n

        def draws(self, T_object_wrist, joints):
            i = np.arange(self.n)
            T = np.repeat(T_object_wrist[None], self.n, axis=0)
            T[:, 0, 3] += 1e-3 * i
            J = np.repeat(joints[None], self.n, axis=0)
            J[:, 0] = i / 100.0
            return T, J

        def qualities(self, T_object_wrist, joints):
            return np.asarray(probe_q[: self.n], dtype=float)

        def __call__(self, T_object_wrist, joints):
            key = -1 if joints[0] == MEAN_J0 else int(round(joints[0] * 100))
            return scores[key]

    def fake_learn(traj, scene, params, cache_dir=None):
        solved.append(traj)
        base = _model()  # the candidate's wrist: tau_r's new last step times the mean's offset from tau_r
        offset = np.linalg.inv(base.source.T_object_wrist[-1]) @ base.T_object_wrist_mean[-1]
        dx = (traj.T_object_wrist[-1] @ offset)[0, 3] - base.T_object_wrist_mean[-1][0, 3]
        key = int(round(dx * 1e3))
        return dataclasses.replace(_model(), source=traj, label=f"candidate {key}")

    def fake_inspect(model, scene, draws, rng, processes=None):
        valid, least_free, *blocked = measures[model.label]  # blocked: how many steps' means' edges
        return types.SimpleNamespace(
            valid_fraction=valid,
            free_fraction=(1.0, least_free, 0.9),
            blocked_mean_steps=tuple(range(blocked[0] if blocked else 0)),
        )

    monkeypatch.setattr(sg, "ClosingPool", FakePool)
    monkeypatch.setattr(sg, "ExpectedQuality", FakeExpected)
    monkeypatch.setattr(sg, "learn_in_scene", fake_learn)
    monkeypatch.setattr(sg, "inspect_model", fake_inspect)
    return solved


MEAN_J0 = float(_model().joints_mean[-1][0])
SCENE = types.SimpleNamespace(name="scene", T_world_object=np.eye(4), cov_object=np.eye(6) * 1e-6)
CONFIG = sg.SceneGraspConfig(probe_draws=12, candidates=5, draws=8, accept_draws=200, resolves=3)


def _probe():
    q = np.zeros(12)
    q[[9, 7, 1, 4, 2, 11]] = [0.30, 0.25, 0.20, 0.15, 0.10, 0.05]  # the best five: 9, 7, 1, 4, 2
    return q


def test_the_model_with_the_largest_valid_times_free_product_is_kept(monkeypatch):
    """Candidates are solved again in the order of their scores (only those above the mean's, at most
    ``resolves``); kept is the largest product valid x least free: 0.15 x 0.505 for candidate 7, not the
    best grasp (9: 0.185 x 0.24) and not the original (0.03 x 0.625)."""
    scores = {-1: 0.005, 9: 0.020, 7: 0.015, 1: 0.012, 4: 0.010, 2: 0.004}
    measures = {
        "original": (0.03, 0.625),
        "candidate 9": (0.185, 0.24),
        "candidate 7": (0.15, 0.505),
        "candidate 1": (0.075, 0.40),
    }
    solved = _install(monkeypatch, _probe(), scores, measures)
    out = sg.adapt_final_grasp(_model(), SCENE, params=object(), config=CONFIG)
    info = out.source.meta["scene_grasp"]
    # candidates are numbered 1.. by their probe quality (draws 9, 7, 1, 4, 2); 0 is the mean
    assert [t["candidate"] for t in info["tried"]] == [1, 2, 3]  # draw 4 is fourth, 2 scores below the mean
    assert len(solved) == 3
    assert info["kept"] is True and info["candidate"] == 2
    assert out.label == "candidate 7"
    assert out.source.meta["scene"] == "demo"  # the trajectory's own meta is kept


def test_a_model_whose_means_path_is_blocked_at_more_steps_is_not_kept(monkeypatch):
    """Candidate 9 has the largest product but its means' path passes through the scene at three steps
    (ham on an arc: a re-solve passed the wall the other way); candidate 7, blocked nowhere, is kept. A
    candidate blocked at no more steps than the original is weighed by its product as before."""
    scores = {-1: 0.005, 9: 0.020, 7: 0.015, 1: 0.012, 4: 0.0, 2: 0.0}
    measures = {
        "original": (0.14, 0.51, 0),
        "candidate 9": (0.245, 0.50, 3),
        "candidate 7": (0.20, 0.50, 0),
        "candidate 1": (0.10, 0.40, 0),
    }
    _install(monkeypatch, _probe(), scores, measures)
    out = sg.adapt_final_grasp(_model(), SCENE, params=object(), config=CONFIG)
    info = out.source.meta["scene_grasp"]
    assert out.label == "candidate 7" and info["candidate"] == 2
    assert info["tried"][0] == {
        "candidate": 1,
        "valid_fraction": 0.245,
        "least_free_fraction": 0.50,
        "blocked_mean_steps": 3,
    }
    measures["original"] = (0.14, 0.51, 3)  # blocked as often as candidate 9: the product decides
    _install(monkeypatch, _probe(), scores, measures)
    assert sg.adapt_final_grasp(_model(), SCENE, params=object(), config=CONFIG).label == "candidate 9"


def test_the_original_stays_when_no_candidate_is_better(monkeypatch):
    scores = {-1: 0.005, 9: 0.020, 7: 0.015, 1: 0.012, 4: 0.010, 2: 0.004}
    measures = {"original": (0.20, 0.60), **{f"candidate {k}": (0.30, 0.30) for k in (9, 7, 1)}}
    _install(monkeypatch, _probe(), scores, measures)
    model = _model()
    out = sg.adapt_final_grasp(model, SCENE, params=object(), config=CONFIG)
    assert out.source.meta["scene_grasp"]["kept"] is False
    assert out.label == "original"
    np.testing.assert_array_equal(out.T_object_wrist_mean, model.T_object_wrist_mean)


def test_a_tie_within_the_draws_noise_keeps_the_original(monkeypatch):
    """Salt in its own scene: the same 3 % valid, 34.5 % free against 32.5 % (200 draws), a gain of 0.1
    standard errors of the difference: the model GTSAM solved from tau_r stays. With ``margin_se = 0`` (the
    bare product rule) the re-solved one would be kept."""
    scores = {-1: 0.005, 9: 0.020, 7: 0.0, 1: 0.0, 4: 0.0, 2: 0.0}
    measures = {"original": (0.03, 0.325), "candidate 9": (0.03, 0.345)}
    _install(monkeypatch, _probe(), scores, measures)
    out = sg.adapt_final_grasp(_model(), SCENE, params=object(), config=CONFIG)
    assert out.label == "original" and out.source.meta["scene_grasp"]["kept"] is False
    bare = dataclasses.replace(CONFIG, margin_se=0.0)
    assert sg.adapt_final_grasp(_model(), SCENE, params=object(), config=bare).label == "candidate 9"


@pytest.mark.parametrize(("margin_se", "kept"), [(1.0, True), (1.9, True), (2.1, False)])
def test_the_margin_in_standard_errors_worked_by_hand(monkeypatch, margin_se, kept):
    """Original 0.2 x 0.5, candidate 0.3 x 0.5, 200 draws: their products' standard errors are
    sqrt((0.25 * 0.16 + 0.04 * 0.25) / 200) = 0.0158 and sqrt((0.25 * 0.21 + 0.09 * 0.25) / 200) = 0.0194,
    the difference's sqrt(0.00025 + 0.000375) = 0.025; the gain 0.05 is two of them."""
    scores = {-1: 0.005, 9: 0.020, 7: 0.0, 1: 0.0, 4: 0.0, 2: 0.0}
    _install(monkeypatch, _probe(), scores, {"original": (0.2, 0.5), "candidate 9": (0.3, 0.5)})
    config = dataclasses.replace(CONFIG, margin_se=margin_se)
    out = sg.adapt_final_grasp(_model(), SCENE, params=object(), config=config)
    assert out.source.meta["scene_grasp"]["kept"] is kept


def test_product_se_against_the_exact_variance():
    """The delta method against the exact variance of the product of two independent binomial
    proportions, Var(a b) = Va Vb + Va E[b]^2 + Vb E[a]^2: they differ by the O(1/n^2) term Va Vb."""
    for p, f, n in [(0.03, 0.325, 200), (0.3, 0.5, 200), (0.15, 0.505, 1000), (0.6, 0.9, 50)]:
        va, vf = p * (1 - p) / n, f * (1 - f) / n
        exact = np.sqrt(va * vf + va * f**2 + vf * p**2)
        assert sg.product_se(p, f, n) == pytest.approx(exact, rel=1.0 / n)
    assert sg.product_se(0.0, 0.4, 200) == 0.0 and sg.product_se(1.0, 1.0, 200) == 0.0


def test_nothing_is_solved_again_when_the_mean_scores_best(monkeypatch):
    scores = {-1: 0.05, 9: 0.020, 7: 0.015, 1: 0.012, 4: 0.010, 2: 0.004}
    solved = _install(monkeypatch, _probe(), scores, {"original": (0.2, 0.6)})
    out = sg.adapt_final_grasp(_model(), SCENE, params=object(), config=CONFIG)
    assert solved == [] and out.source.meta["scene_grasp"]["tried"] == []


def test_tau_r_keeps_its_offset_from_the_mean_at_the_candidate(monkeypatch):
    """The blend moves tau_r's last step so that the model's offset from tau_r (the clearances' doing)
    puts the mean on the candidate: ``T_blend[-1] @ (tau_r[-1]^-1 @ mean[-1]) = candidate``, and the
    joints by the candidate's change from the mean; the steps before the blend are untouched."""
    scores = {-1: 0.0, 9: 0.02, 7: 0.0, 1: 0.0, 4: 0.0, 2: 0.0}
    solved = _install(monkeypatch, _probe(), scores, {"original": (0.0, 0.5), "candidate 9": (0.1, 0.5)})
    model = _model()
    sg.adapt_final_grasp(model, SCENE, params=object(), config=CONFIG)
    (moved,) = solved
    tau, T_mean = model.source.T_object_wrist, model.T_object_wrist_mean[-1]
    T_cand = T_mean.copy()
    T_cand[0, 3] += 9e-3  # probe draw 9, in the object frame (the scene's object at the origin)
    np.testing.assert_allclose(moved.T_object_wrist[-1] @ np.linalg.inv(tau[-1]) @ T_mean, T_cand, atol=1e-12)
    J_cand = model.joints_mean[-1].copy()
    J_cand[0] = 0.09
    expected = sah.clip_joints(model.source.joints[-1] + J_cand - model.joints_mean[-1])
    np.testing.assert_allclose(moved.joints[-1], expected, atol=1e-12)
    n_fixed = T_STEPS - CONFIG.blend_steps
    np.testing.assert_array_equal(moved.T_object_wrist[:n_fixed], tau[:n_fixed])


def test_bad_settings_and_a_model_without_its_trajectory_are_refused():
    with pytest.raises(InputError):
        sg.SceneGraspConfig(resolves=0)
    with pytest.raises(InputError):
        sg.SceneGraspConfig(seed=-1)
    with pytest.raises(InputError):
        sg.SceneGraspConfig(margin_se=float("nan"))
    with pytest.raises(InputError, match="source trajectory"):
        sg.adapt_final_grasp(_model(source=False), SCENE)


def test_the_cli_line_names_what_was_kept():
    from pbdgrasp.cli.infer import scene_grasp_line

    found = {
        "kept": True,
        "candidate": 2,
        "before": {"valid_fraction": 0.03, "least_free_fraction": 0.625},
        "tried": [
            {"candidate": 1, "valid_fraction": 0.185, "least_free_fraction": 0.24},
            {"candidate": 2, "valid_fraction": 0.15, "least_free_fraction": 0.505},
        ],
    }
    assert scene_grasp_line(found, "jam_hole") == (
        "final grasp in jam_hole: chosen again (2 candidate(s) solved again; last-step valid, least free: "
        "3%, 62%; with it 15%, 50%)"
    )
    found.update(kept=False, candidate=None)
    assert "kept as solved" in scene_grasp_line(found, "jam_hole")
