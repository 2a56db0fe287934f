"""The simulated person and what it wants: `OperatorProfile` (the distributions each
operator's own delay, decision time, noise, Fitts' law, resistance, patience and speed caps are
drawn from) and `Intention` (the stages it wants the robot to reach, what it settles for when
the robot resists, and its change of mind). `app/operator/closed_loop.py` is how it acts on
them; docs/operator.md says where each value comes from.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration.se3 import HandState
from dsteleop.errors import ConfigError

Array = NDArray[np.float64]
Interval = tuple[float, float]


@dataclass(frozen=True)
class OperatorProfile:
    """The person: distributions an interval (lo, hi) is drawn from uniformly, per operator.

    Attributes:
        delay_s: visual feedback delay [s].
        decision_s: decision time added to the delay in every dwell [s].
        angle_noise_rad: sd of the perceived robot orientation, per axis [rad].
        openness_noise: sd of the perceived finger openness.
        fitts_a_s, fitts_b_s: Fitts' law of a submovement, T = a + b log2(1 + A / W) [s].
        min_move_s: shortest submovement [s].
        endpoint_noise: sd of a submovement's endpoint error, as a share of its amplitude.
        resisted_below: the robot's perceived progress, as a share of what was asked, under
            which a submovement counts as resisted.
        push_gain_step, push_gain_max: how much harder the operator pushes when resisted.
        resisted_before_pause: resisted submovements in a row before a pause.
        pause_s: length of that pause [s].
        hold_s: satisfied and still this long: done [s].
        patience_s: gives up after this long without being done [s].
        detect_k: a submovement is judged resisted only in a group (translation, rotation,
            fingers) where it asked for more than detect_k times the perception noise: a
            person cannot see the robot lag behind a movement smaller than that.
        v_cap_mps, w_cap_radps, g_cap_per_s: the hand's speed caps (the robot's limits less
            a margin, so the hand is never clipped by the saturation of U_human).
    """

    delay_s: Interval = (0.15, 0.30)
    decision_s: Interval = (0.10, 0.25)
    angle_noise_rad: float = 0.02
    openness_noise: float = 0.02
    fitts_a_s: float = 0.25
    fitts_b_s: float = 0.15
    min_move_s: float = 0.3
    endpoint_noise: float = 0.05
    resisted_below: float = 0.5
    push_gain_step: float = 1.5
    push_gain_max: float = 3.0
    resisted_before_pause: int = 3
    pause_s: Interval = (0.5, 1.5)
    hold_s: float = 0.5
    patience_s: float = 30.0
    detect_k: float = 3.0
    v_cap_mps: float = 0.2375
    w_cap_radps: float = 0.95
    g_cap_per_s: float = 3.8

    def __post_init__(self) -> None:
        for name in ("delay_s", "decision_s", "pause_s"):
            lo, hi = getattr(self, name)
            if not (math.isfinite(lo) and math.isfinite(hi) and 0 <= lo <= hi):
                raise ConfigError(f"{name} must be an interval 0 <= lo <= hi, got {(lo, hi)!r}")
        for name in (
            "angle_noise_rad", "openness_noise", "fitts_a_s", "fitts_b_s",
            "min_move_s", "endpoint_noise", "hold_s",
        ):  # fmt: skip
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be finite and >= 0, got {v!r}")
        for name in (
            "v_cap_mps", "w_cap_radps", "g_cap_per_s", "patience_s", "detect_k",
        ):  # fmt: skip
            if not getattr(self, name) > 0:
                raise ConfigError(f"{name} must be > 0")
        if not (0 < self.resisted_below < 1 and 1 <= self.push_gain_step <= self.push_gain_max):
            raise ConfigError("resisted_below in (0, 1) and 1 <= push_gain_step <= push_gain_max")

    def for_robot(
        self, v_max_mps: float, w_max_radps: float, g_max_per_s: float, share: float = 0.95
    ) -> OperatorProfile:
        """The same person with speed caps at `share` of a robot's limits (95 %: just under
        them; lower where the input adds jitter to the hand's speed, as a camera does)."""
        if not 0 < share <= 1:
            raise ConfigError(f"share must be in (0, 1], got {share!r}")
        return replace(
            self, v_cap_mps=share * v_max_mps, w_cap_radps=share * w_max_radps,
            g_cap_per_s=share * g_max_per_s,
        )  # fmt: skip


@dataclass(frozen=True)
class Intention:
    """What N operators want the robot to do: S stages each (rows may use fewer).

    Attributes:
        targets: the robot poses wanted, batch (N, S).
        tolerance: (N, S, 3) position [m], angle [rad] and openness tolerance of each stage.
        mask: (N, S, D) 1 where a dimension counts in a stage: the operator plans and judges
            a stage on those dimensions only (a "y first" stage masks all but y).
        n_stages: (N,) stages each row uses (its last is its final one).
        turn_within_m: (N,) the orientation part of a submovement is planned only within
            this distance of the stage's target position [m].
        settle_targets: what a row settles for after resistance (N, S), or None (it never
            settles): the task's own goals, where `targets` hold the person's preference.
        settle_tolerance: (N, S, 3) the tolerances it then accepts (the task's).
        settle_after: (N,) the resistance pause at which a row settles (1: its first; a
            count above any trial's pauses: never), or None (every row at its first).
        change_at_s: (N,) when a row changes its mind [s] (inf: never), or None (no row
            does): its targets become `change_targets` and its settle targets
            `change_settle` from then on.
        change_targets: the targets after the change (N, S), with `change_at_s`.
        change_settle: the settle targets after the change (N, S), where `settle_targets`
            is given.
    """

    targets: HandState
    tolerance: Array
    mask: Array
    n_stages: NDArray[np.int64]
    turn_within_m: Array
    settle_targets: HandState | None = None
    settle_tolerance: Array | None = None
    settle_after: NDArray[np.int64] | None = None
    change_at_s: Array | None = None
    change_targets: HandState | None = None
    change_settle: HandState | None = None

    def __post_init__(self) -> None:
        if (self.settle_targets is None) != (self.settle_tolerance is None):
            raise ConfigError("settle_targets and settle_tolerance go together")
        if self.settle_after is not None and (self.settle_after < 1).any():
            raise ConfigError("settle_after counts pauses from 1")
        if (self.change_at_s is None) != (self.change_targets is None):
            raise ConfigError("change_at_s and change_targets go together")
        if (self.change_settle is not None) and (
            self.change_at_s is None or self.settle_targets is None
        ):
            raise ConfigError("change_settle needs change_at_s and settle_targets")

    def take(self, keep: NDArray[np.bool_]) -> Intention:
        st, tol = self.settle_targets, self.settle_tolerance
        ct, cs = self.change_targets, self.change_settle
        return Intention(
            self.targets.take(keep), self.tolerance[keep], self.mask[keep], self.n_stages[keep],
            self.turn_within_m[keep], None if st is None else st.take(keep),
            None if tol is None else tol[keep],
            None if self.settle_after is None else self.settle_after[keep],
            None if self.change_at_s is None else self.change_at_s[keep],
            None if ct is None else ct.take(keep), None if cs is None else cs.take(keep),
        )  # fmt: skip

    def changed(self, rows: NDArray[np.intp]) -> Intention:
        """A copy in which rows `rows` have changed their mind: their targets (and settle
        targets) are the change's."""
        if self.change_targets is None:
            return self
        targets = put_rows(self.targets, rows, self.change_targets.take(rows))
        settle = self.settle_targets
        if settle is not None and self.change_settle is not None:
            settle = put_rows(settle, rows, self.change_settle.take(rows))
        return replace(self, targets=targets, settle_targets=settle)

    def of_rows(self, idx: NDArray[np.intp], settled: NDArray[np.bool_]) -> tuple[HandState, Array]:
        """Rows idx's targets (n, S) and tolerances (n, S, 3): the settle ones where
        `settled` (n,)."""
        target, tol = self.targets.take(idx), self.tolerance[idx]
        if self.settle_targets is None or self.settle_tolerance is None or not settled.any():
            return target, tol
        alt = self.settle_targets.take(idx)
        s = settled[:, None]
        target = HandState(
            np.where(s[..., None], alt.position, target.position),
            np.where(s[..., None, None], alt.rotation, target.rotation),
            np.where(s[..., None], alt.openness, target.openness),
        )
        return target, np.where(s[..., None], self.settle_tolerance[idx], tol)


def put_rows(X: HandState, idx: NDArray[np.intp], Y: HandState) -> HandState:
    """X with rows idx replaced by Y's rows (a copy; any batch after the rows)."""
    p, R, g = X.position.copy(), X.rotation.copy(), X.openness.copy()
    p[idx], R[idx], g[idx] = Y.position, Y.rotation, Y.openness
    return HandState(p, R, g)
