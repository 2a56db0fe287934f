"""The four corrections of the arbitration's reading (docs/METHOD.md §3-5), each pinned.

1. eq (6)'s u(cur, prev) is gated by a speed (per group), not by eq (4)'s 1e-3 floor applied
   to a per-tick difference (which zeroed every motion below 3 cm/s and 0.03 rad/s);
2. a group with one moving component (the planar heading) does not turn a slow wander into a
   +-1 direction;
3. the DS windows restart at each segment (B back to 1 for the place goal);
4. eq (4)'s denominator floor is a task-scale length, so P is smooth in a dimension whose goal
   equals its start.
"""

from __future__ import annotations

import itertools

import numpy as np

from dsteleop.app.loop import LoopConfig, TeleopLoop
from dsteleop.app.loop.timing import ManualClock
from dsteleop.arbitration import (
    ArbitrationConfig,
    ArbitrationInput,
    ArbitrationStep,
    HandState,
    Mode,
    make_arbiter,
)
from dsteleop.robot.task import Phase

from .fakes import DT, ScriptedHand, fake_world, state


def planar(x: float, y: float, heading: float) -> HandState:
    return HandState.from_rotvec([x, y, 0.0], [0.0, 0.0, heading], np.zeros(0))


def step(inp: ArbitrationInput, mode: Mode = Mode.DS) -> ArbitrationStep:
    arb = make_arbiter(mode)
    _, s = arb.step(arb.initial_state(6 + inp.X_current.n_fingers), inp)
    return s


def test_1_a_slow_hand_keeps_its_direction_in_eq_6() -> None:
    """The hand moves along +y at 1 cm/s (0.33 mm a tick): its u(cur, prev) is +y."""
    v = 0.01
    H, Hp = planar(0.0, v * DT, 0.0), planar(0.0, 0.0, 0.0)
    Hs = planar(0.0, -0.1, 0.0)  # its segment started 10 cm behind: u(cur, start) = +y
    R = planar(0.3, 0.3, 0.0)
    s = step(
        ArbitrationInput(
            X_human=H,
            X_human_prev=Hp,
            X_human_start=Hs,
            X_current=R,
            X_prev=R,
            X_start=R,
            X_goal=planar(0.3, 0.4, 0.0),
            dt=DT,
        )
    )
    U_y = v / ArbitrationConfig().v_max_mps
    np.testing.assert_allclose(s.psi_human[1], U_y - 1.0 - 1.0, atol=1e-9)


def test_1_a_hand_still_within_the_noise_floor_has_no_direction() -> None:
    cfg = ArbitrationConfig()
    drift = 0.5 * cfg.still_speed_mps * DT  # half the still speed
    H, Hp = planar(drift, 0.0, 0.0), planar(0.0, 0.0, 0.0)
    R = planar(0.3, 0.3, 0.0)
    s = step(
        ArbitrationInput(
            X_human=H,
            X_human_prev=Hp,
            X_human_start=H,
            X_current=R,
            X_prev=R,
            X_start=R,
            X_goal=planar(0.3, 0.4, 0.0),
            dt=DT,
        )
    )
    # u(cur, prev) = 0 and u(cur, start) = 0: psi is the action's own term.
    np.testing.assert_allclose(s.psi_human, s.U_human / cfg.v_max(0), atol=1e-12)


def test_2_a_slow_heading_wander_is_not_a_unit_direction() -> None:
    """The planar heading turns by 0.0015 rad a tick (0.045 rad/s, a wander): no +-1."""
    H, Hp = planar(0.0, 0.0, 0.0015), planar(0.0, 0.0, 0.0)
    R = planar(0.3, 0.3, 0.0)
    s = step(
        ArbitrationInput(
            X_human=H,
            X_human_prev=Hp,
            X_human_start=H,
            X_current=R,
            X_prev=R,
            X_start=R,
            X_goal=planar(0.3, 0.4, 0.5),
            dt=DT,
        )
    )
    cfg = ArbitrationConfig()
    assert abs(s.psi_human[5] - s.U_human[5] / cfg.w_max_radps) < 1e-12
    # A real turn (0.3 rad/s), 0.2 rad into its segment, keeps its direction.
    H2, Hs = planar(0.0, 0.0, 0.3 * DT), planar(0.0, 0.0, -0.2)
    s2 = step(
        ArbitrationInput(
            X_human=H2,
            X_human_prev=Hp,
            X_human_start=Hs,
            X_current=R,
            X_prev=R,
            X_start=R,
            X_goal=planar(0.3, 0.4, 0.5),
            dt=DT,
        )
    )
    np.testing.assert_allclose(s2.psi_human[5], s2.U_human[5] / cfg.w_max_radps - 2.0, atol=1e-9)


def test_3_in_ds_the_place_segment_starts_with_b_one() -> None:
    world = fake_world(start=state((0.5, 0.3, 0.4)))
    hand = ScriptedHand(lambda t: state((0.5, 0.3 - 0.05 * t, 0.4 - 0.05 * t)))
    loop = TeleopLoop(LoopConfig(mode=Mode.DS), hand, *world, ManualClock(0.0))
    place = None
    for k in range(1800):
        loop.clock.sleep_until(k * DT)
        r = loop.tick(k * DT)
        if r.phase is Phase.PLACE:
            place = loop.tick((k + 1) * DT)
            break
    assert place is not None and place.step is not None
    # The first tick of the segment averages its raw B with four ones (window 5).
    W = loop.config.arbitration.window
    assert np.all(place.step.B >= (W - 1) / W - 1e-12)
    assert loop.state.filter.count == 1


def test_4_p_is_smooth_where_the_goal_equals_the_start() -> None:
    """z: goal z == start z. P(R_z) falls smoothly with the distance, no step at 1 mm."""
    start = state((0.5, 0.3, 0.4))
    goal = state((0.5, 0.1, 0.4))
    P = []
    for dz in (0.0005, 0.002, 0.005, 0.01):
        cur = state((0.5, 0.2, 0.4 + dz))
        s = step(
            ArbitrationInput(
                X_human=cur,
                X_human_prev=cur,
                X_human_start=cur,
                X_current=cur,
                X_prev=cur,
                X_start=start,
                X_goal=goal,
                dt=DT,
            ),
            Mode.S,
        )
        P.append(float(s.P_robot[2]))
    assert all(a > b for a, b in itertools.pairwise(P))  # falls with the distance
    assert P[0] > 0.95 and P[-1] > 0.4  # at 1 cm it still counts as near (task scale)
