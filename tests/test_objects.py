"""The objects world (`--world objects`, app/study/objects.py, docs/operator.md): several
objects, the person wants one and may change its mind, the robot infers which from the hand
and knows each object only up to its perception error. A test per mechanism, the belief in
the study's world as rates over seeds, the study's outcome structure, and bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dsteleop.app.operator.closed_loop import Intention
from dsteleop.app.study.objects import Objects
from dsteleop.arbitration.se3 import stack
from dsteleop.errors import ConfigError
from tests.test_operator_closed_loop import one_stage, operators, planar

DT = 1.0 / 30.0

# --- the world's geometry and perception -------------------------------------------------------


def test_objects_lie_in_a_row_across_the_view_a_hands_breadth_apart() -> None:
    o = Objects()
    xy = o.positions((0.30, 0.40))
    assert xy.shape == (3, 2)
    assert xy[:, 0] == pytest.approx([0.30] * 3)
    assert np.diff(xy[:, 1]) == pytest.approx([0.08, 0.08])
    assert xy[:, 1].mean() == pytest.approx(0.40)
    assert Objects(count=1).positions((0.3, 0.4)).tolist() == [[0.3, 0.4]]


def test_the_perception_error_is_larger_along_the_view_than_across_it() -> None:
    """The error's sd along the camera's view is the depth sd, across it the lateral sd, and
    the heading's its own: measured over many draws (5 %), for the study's view (base x) and
    an oblique one; `perception_sd` is the sd along each base axis."""
    o = Objects()
    z = np.random.default_rng(0).standard_normal((200_000, 3))
    for axis in ((1.0, 0.0, 0.0), (0.6, 0.8, 0.0)):
        e = o.perception_error(axis, z)
        a = np.array(axis[:2])
        across = np.array([-a[1], a[0]])
        assert np.std(e[:, :2] @ a) == pytest.approx(0.02, rel=0.05)
        assert np.std(e[:, :2] @ across) == pytest.approx(0.005, rel=0.05)
        assert np.std(e[:, 2]) == pytest.approx(0.05, rel=0.05)
        assert e.std(axis=0) == pytest.approx(o.perception_sd(axis), rel=0.05)
    assert o.perception_sd((1.0, 0.0, 0.0)) == pytest.approx([0.02, 0.005, 0.05])


@pytest.mark.parametrize(
    ("field", "value"),
    [
        ("count", 0),
        ("count", 10),
        ("count", 2.0),
        ("spacing_m", 0.0),
        ("spacing_m", 0.5),
        ("perception_depth_m", -0.01),
        ("perception_lateral_m", math.nan),
        ("perception_heading_rad", 2.0),
        ("change_share", 1.5),
        ("change_at_s", (3.0, 1.0)),
        ("change_at_s", (-1.0, 1.0)),
    ],
)
def test_a_value_out_of_range_is_a_config_error_naming_it(field: str, value: object) -> None:
    with pytest.raises(ConfigError, match=field):
        Objects(**{field: value})  # type: ignore[arg-type]


def test_objects_within_the_tasks_and_the_persons_tolerance_are_refused() -> None:
    Objects(spacing_m=0.05).check(0.03, 0.015)
    with pytest.raises(ConfigError, match="not be distinct"):
        Objects(spacing_m=0.04).check(0.03, 0.015)
    Objects(count=1, spacing_m=0.01).check(0.03, 0.015)  # one object: nothing to tell apart


# --- the person: a change of mind --------------------------------------------------------------


def test_a_person_who_changes_its_mind_goes_to_the_new_object_from_its_next_plan() -> None:
    """Against a robot that follows the hand (manual), people who change their mind at 1.5 s
    end at the new object, those who do not at the first; no one changes before its time,
    and a person who has committed before its time does not change any more."""
    n = 6
    first, second = planar(0.3, 0.32, 0.5), planar(0.3, 0.48, 0.5)
    it = one_stage(first, n, tol=(0.01, 0.2))
    change_at = np.array([1.5, 1.5, 1.5, np.inf, np.inf, 0.0])
    intention = Intention(
        it.targets, it.tolerance, it.mask, it.n_stages, it.turn_within_m,
        change_at_s=change_at, change_targets=stack([stack([second])] * n),
    )  # fmt: skip
    op = operators(n, seed=2, intention=intention)
    X = op.start
    op.observe(0.0, X)
    for k in range(1, round(20.0 / DT) + 1):
        t = k * DT
        X = op.hand(t)
        op.observe(t, X)
        assert np.array_equal(op.changed, t >= change_at - 1e-9)
        if op.done.all():
            break
    assert op.committed.all()
    y = X.position[:, 1]
    assert np.abs(y[[0, 1, 2, 5]] - 0.48).max() < 0.015
    assert np.abs(y[[3, 4]] - 0.32).max() < 0.015


def test_a_change_also_changes_what_the_person_would_settle_for() -> None:
    n = 2
    first, second = planar(0.3, 0.32, 0.5), planar(0.3, 0.48, 0.5)
    it = one_stage(first, n)
    both = stack([stack([second])] * n)
    intention = Intention(
        it.targets, it.tolerance, it.mask, it.n_stages, it.turn_within_m,
        it.targets, np.tile([0.03, 0.35, 1.0], (n, 1, 1)), None,
        np.array([0.0, np.inf]), both, both,
    )  # fmt: skip
    changed = intention.changed(np.array([0]))
    assert changed.targets.position[:, 0, 1] == pytest.approx([0.48, 0.32])
    assert changed.settle_targets is not None
    assert changed.settle_targets.position[:, 0, 1] == pytest.approx([0.48, 0.32])
    kept = changed.take(np.array([False, True]))
    assert kept.change_at_s is not None and kept.change_at_s.tolist() == [np.inf]
    with pytest.raises(ValueError, match="go together"):
        Intention(
            it.targets, it.tolerance, it.mask, it.n_stages, it.turn_within_m,
            change_at_s=np.zeros(n),
        )  # fmt: skip
