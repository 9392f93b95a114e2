"""Virtual fingers: groupings of hand-built force directions whose best grouping is known."""

from __future__ import annotations

import numpy as np
import pytest

from retarget.virtual_fingers import (
    HUMAN_FINGERS,
    choose_virtual_fingers,
    dispersion,
    grasp_cohesive_index,
    groupings,
)

#: Absolute tolerance on cohesive indices computed in closed form.
INDEX_ATOL = 1e-12


def _dirs(*angles_deg):
    """Unit force directions in the x-z plane at the given angles from +x."""
    a = np.deg2rad(np.asarray(angles_deg, dtype=float))
    return np.stack([np.cos(a), np.zeros_like(a), np.sin(a)], axis=-1)


def test_groupings_enumerate_every_partition():
    adjacent = groupings(4, 3)
    assert adjacent == [((0,), (1,), (2, 3)), ((0,), (1, 2), (3,)), ((0, 1), (2,), (3,))]
    every = groupings(4, 3, adjacent_only=False)
    assert len(every) == 6  # Stirling number S(4, 3)
    for g in every:
        assert sorted(i for grp in g for i in grp) == [0, 1, 2, 3]
    assert len(groupings(4, 2, adjacent_only=False)) == 7  # S(4, 2)
    with pytest.raises(ValueError, match="cannot group"):
        groupings(3, 4)


def test_dispersion_closed_form():
    assert dispersion(_dirs(0, 0, 0)) == pytest.approx(0.0, abs=INDEX_ATOL)
    assert dispersion(_dirs(0, 180)) == pytest.approx(1.0, abs=INDEX_ATOL)
    assert dispersion(_dirs(0, 90)) == pytest.approx(1 - np.cos(np.pi / 4), abs=INDEX_ATOL)
    # Not unit inputs are normalised first.
    assert dispersion(3.0 * _dirs(0, 90)) == pytest.approx(1 - np.cos(np.pi / 4), abs=INDEX_ATOL)
    g = grasp_cohesive_index(_dirs(0, 10, 50, 90), [(0,), (1, 2), (3,)])
    assert g == pytest.approx(2 * (1 - np.cos(np.deg2rad(20))), abs=INDEX_ATOL)


@pytest.mark.parametrize(
    "angles, groups, human_for_robot",
    [
        # middle and ring push alike: the paper's ham can result.
        (
            (0, 40, 42, 90),
            (("index",), ("middle", "ring"), ("little",)),
            ("thumb", "index", "middle", "little"),
        ),
        # ring and little alike: the paper's result for the other objects.
        (
            (0, 30, 60, 61),
            (("index",), ("middle",), ("ring", "little")),
            ("thumb", "index", "middle", "ring"),
        ),
        # index and middle alike: the SAH middle finger follows the human ring finger.
        (
            (10, 11, 60, 90),
            (("index", "middle"), ("ring",), ("little",)),
            ("thumb", "index", "ring", "little"),
        ),
    ],
)
def test_most_similar_neighbours_are_grouped(angles, groups, human_for_robot):
    vf = choose_virtual_fingers(_dirs(*angles))
    assert vf.groups == groups
    assert vf.human_for_robot == human_for_robot
    assert vf.human_indices == tuple(HUMAN_FINGERS.index(f) for f in human_for_robot)
    assert vf.cohesive_index == min(score for _, score in vf.candidates)
    assert len(vf.candidates) == 3
    assert vf.groups[0][0] in vf.describe()


def test_non_adjacent_grouping_only_when_allowed():
    # index and ring push exactly alike; middle and little point elsewhere.
    d = _dirs(0, 70, 0, 140)
    assert choose_virtual_fingers(d, adjacent_only=False).groups == (
        ("index", "ring"),
        ("middle",),
        ("little",),
    )
    adjacent = choose_virtual_fingers(d)
    assert all(
        len(g) == 1 or g in (("index", "middle"), ("middle", "ring"), ("ring", "little"))
        for g in adjacent.groups
    )


def test_fewer_virtual_fingers():
    vf = choose_virtual_fingers(_dirs(0, 1, 90, 91), n_virtual=2)
    assert vf.groups == (("index", "middle"), ("ring", "little"))
    assert vf.human_for_robot == ("thumb", "index", "ring")


@pytest.mark.parametrize(
    "directions, kwargs, match",
    [
        (np.zeros((4, 3)), {}, "non-zero"),
        (np.ones((5, 3)), {}, "shape"),
        (np.full((4, 3), np.nan), {}, "finite"),
        (np.ones((4, 3)), {"n_virtual": 4}, "n_virtual"),
    ],
)
def test_invalid_input(directions, kwargs, match):
    with pytest.raises(ValueError, match=match):
        choose_virtual_fingers(directions, **kwargs)
