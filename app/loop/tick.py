"""One tick of the loop as pure functions: state in, state out.

A tick has two halves around the robot (`runner.TeleopLoop` calls them and the ports):

    decide(state, input, goal, now)  ->  state', Decision(X_next, U_cmd, step, status)
        fresh hand (valid, age <= stale_limit_s):
            the arbitration, eq (1)-(8), integrating eq (2) from the commanded reference
        no fresh hand, policy "halt":
            U_cmd = U_at_loss * ramp, the ramp falling 1 -> 0 over halt_ramp_s, then 0: the
            command is 0 within stale_limit_s + halt_ramp_s of the last fresh sample, and a
            stale command is never repeated
        no fresh hand, policy "assist":
            alpha = 1 on every dimension at assist_speed of the policy's speed, until the
            robot is within assist_goal_tolerance_m of the goal
        told to halt (`halt`: the robot is lost, or the operator pressed Stop):
            the halt ramp as for a lost hand, whatever the hand does and whatever the policy
    plant.apply(X_next)
    absorb(state', plant_step)  ->  state'', segment ended?
        the achieved state, the outcome, and at the end of a pick or place segment: one more
        attempt in the operator history (eq 6), new start states for both agents, fresh DS
        windows (B restarts at 1 for each goal)

Input age is measured on the loop's clock from the capture time, less the injected delay.
When the hand comes back after a loss (or first appears), the caller re-anchors the mapping
so that the hand maps to where the command was (`anchor_target`) before `decide`, and the
first fresh tick has U_human = 0: the robot does not jump.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.loop.config import LoopConfig, LostPolicy
from dsteleop.app.ports import NO_HAND, HumanInput, PlantStep
from dsteleop.app.session.schema import Status
from dsteleop.arbitration import (
    Arbiter,
    ArbitrationInput,
    ArbitrationStep,
    FilterState,
    HandState,
    Mode,
    OperatorHistory,
    make_arbiter,
)
from dsteleop.arbitration.policy import advance_reference
from dsteleop.robot.task import Outcome

Array = NDArray[np.float64]

NO_INPUT = "no input yet"
STALLED = "camera stalled"
FINISHED = "task finished"
#: The reason while the operator's stop is latched (the page's Stop, until Resume).
STOPPED = "stopped by the operator"


@dataclass(frozen=True)
class LoopState:
    """What the loop remembers between ticks (all states in the robot base frame).

    Attributes:
        X_current: the robot's achieved state now; X_prev: one tick ago.
        X_start: the robot's state when the active segment started.
        X_ref: the commanded reference eq (2) integrates from (the previous X_next).
        X_human_prev: the hand at the previous fresh tick (None after a loss: U_human = 0).
        X_human_start: the hand when the active segment started (None before the first).
        X_human_last: the last fresh hand (the operator's command in the view).
        filter: the DS windows.
        lost, reason, t_lost_s: no fresh hand since `t_lost_s` [s], and why.
        U_last: the last commanded velocity; U_at_loss: the one when the hand was lost.
        outcome: the task's outcome once decided.
        history: the operator's previous attempts (eq 6).
    """

    X_current: HandState
    X_prev: HandState
    X_start: HandState
    X_ref: HandState
    X_human_prev: HandState | None
    X_human_start: HandState | None
    X_human_last: HandState | None
    filter: FilterState
    lost: bool
    reason: str
    t_lost_s: float | None
    U_last: Array
    U_at_loss: Array
    outcome: Outcome | None
    history: OperatorHistory


@dataclass(frozen=True)
class Decision:
    """The first half of a tick: what to command and why."""

    X_next: HandState
    U_cmd: Array
    step: ArbitrationStep | None
    status: Status
    reason: str


def start(X_current: HandState, arbiter: Arbiter, history: OperatorHistory) -> LoopState:
    """The state at a task reset: the robot at `X_current`, no hand yet."""
    D = 6 + X_current.n_fingers
    zeros = np.zeros(D)
    return LoopState(
        X_current=X_current,
        X_prev=X_current,
        X_start=X_current,
        X_ref=X_current,
        X_human_prev=None,
        X_human_start=None,
        X_human_last=None,
        filter=arbiter.initial_state(D),
        lost=True,
        reason=NO_INPUT,
        t_lost_s=None,
        U_last=zeros,
        U_at_loss=zeros,
        outcome=None,
        history=history,
    )


def staleness(inp: HumanInput | None, now_s: float, cfg: LoopConfig, ended: str = "") -> str:
    """Why the input cannot drive the robot now ("" when it can): no input yet, no hand,
    invalid (NaN/inf) data, or a camera that stalled (older than stale_limit_s); `ended`
    (e.g. "video ended") instead of the last two once the source has ended."""
    if inp is None:
        return ended or NO_INPUT
    age = now_s - cfg.input_delay_s - inp.t_capture_s
    stale = not math.isfinite(age) or age > cfg.stale_limit_s
    if ended and stale:
        return ended
    if inp.X_human is None:
        return inp.reason or NO_HAND
    if stale:
        return STALLED
    return ""


def anchor_target(state: LoopState) -> HandState:
    """Where a returning hand maps to: the last command, or the robot at the first hand."""
    return state.X_human_last or state.X_current


def decide(
    state: LoopState,
    cfg: LoopConfig,
    arbiter: Arbiter,
    inp: HumanInput | None,
    goal: HandState | None,
    now_s: float,
    history_term: Array | None,
    ended: str = "",
    halt: str = "",
    confidence: Array | None = None,
    confidence_joint: float | None = None,
) -> tuple[LoopState, Decision]:
    """The first half of a tick (module docstring). `inp` is already re-anchored; `ended`
    says why there is no more input once the source has ended ("" while it runs); `halt`
    why the robot must not be driven whatever the hand does: `ports.ROBOT_LOST` (its state
    is missing or stale) or `STOPPED` (the operator's latched stop). The loop then halts
    exactly as for a lost hand, never assisted ("" while it may be driven). `confidence`
    and `confidence_joint`: the robot's confidence in `goal` (a belief's, `inference`), per
    dimension and joint; None: a goal it is told (1)."""
    dt = cfg.dt_s
    reason = halt or staleness(inp, now_s, cfg, ended)
    if not reason and inp is not None and inp.X_human is not None and goal is not None:
        X_h = inp.X_human
        X_h_prev = X_h if state.lost or state.X_human_prev is None else state.X_human_prev
        X_h_start = state.X_human_start or X_h
        filt, step = arbiter.step(
            state.filter,
            ArbitrationInput(
                X_human=X_h,
                X_human_prev=X_h_prev,
                X_human_start=X_h_start,
                X_current=state.X_current,
                X_prev=state.X_prev,
                X_start=state.X_start,
                X_goal=goal,
                dt=dt,
                history_term=history_term,
                X_ref=state.X_ref,
                confidence=confidence,
                confidence_joint=confidence_joint,
            ),
        )
        new = replace(
            state,
            X_human_prev=X_h,
            X_human_start=X_h_start,
            X_human_last=X_h,
            filter=filt,
            lost=False,
            reason="",
            t_lost_s=None,
            U_last=step.U_out,
            X_ref=step.X_next,
        )
        return new, Decision(step.X_next, step.U_out, step, Status.TRACKING, "")
    t_lost = now_s if not state.lost or state.t_lost_s is None else state.t_lost_s
    U_at_loss = state.U_last if not state.lost else state.U_at_loss
    done = goal is None  # the task has its outcome: the robot halts, whatever the hand does
    reason = outcome_words(state.outcome) if done else (reason or NO_INPUT)
    assisted: ArbitrationStep | None = None
    if cfg.lost_policy is LostPolicy.ASSIST and goal is not None and not halt:
        U_cmd, assisted = _assist(state, cfg, goal)
        status = Status.ASSIST
    else:
        ramp = max(0.0, 1.0 - (now_s - t_lost) / cfg.halt_ramp_s)
        U_cmd = U_at_loss * ramp
        status = Status.FINISHED if done else Status.LOST
    X_next = advance_reference(state.X_ref, state.X_current, U_cmd, dt, cfg.arbitration)
    new = replace(
        state,
        X_human_prev=None,
        lost=True,
        reason=reason,
        t_lost_s=t_lost,
        U_at_loss=U_at_loss,
        U_last=U_cmd,
        X_ref=X_next,
    )
    return new, Decision(X_next, U_cmd, assisted, status, reason)


def outcome_words(outcome: Outcome | None) -> str:
    """The outcome as the status says it: "success (in_bin)", "failure (timeout)"."""
    if outcome is None:
        return FINISHED
    return f"{'success' if outcome.success else 'failure'} ({outcome.reason})"


def _assist(
    state: LoopState, cfg: LoopConfig, goal: HandState
) -> tuple[Array, ArbitrationStep | None]:
    """alpha = 1 on every dimension at reduced speed, until the goal is reached."""
    D = 6 + state.X_current.n_fingers
    if np.linalg.norm(goal.position - state.X_current.position) < cfg.assist_goal_tolerance_m:
        return np.zeros(D), None
    X_h = state.X_human_last or state.X_current
    auto = make_arbiter(Mode.AUTONOMOUS, cfg.arbitration)
    _, step = auto.step(
        auto.initial_state(D),
        ArbitrationInput(
            X_human=X_h,
            X_human_prev=X_h,
            X_human_start=state.X_human_start or X_h,
            X_current=state.X_current,
            X_prev=state.X_prev,
            X_start=state.X_start,
            X_goal=goal,
            dt=cfg.dt_s,
        ),
    )
    return step.U_robot * cfg.assist_speed, step


def absorb(state: LoopState, result: PlantStep, arbiter: Arbiter) -> tuple[LoopState, bool]:
    """The second half of a tick: the robot's report. Returns the state and whether a
    segment ended (the place goal became active, or the outcome was decided)."""
    new = replace(state, X_prev=state.X_current, X_current=result.X_current)
    ended = False
    if result.outcome is not None and state.outcome is None:
        new = replace(new, outcome=result.outcome)
        ended = True  # the place segment ends with the outcome
    elif result.segment_changed:
        ended = True
    if ended:
        new = _end_segment(new, arbiter)
    return new, ended


def _end_segment(state: LoopState, arbiter: Arbiter) -> LoopState:
    """A pick or place segment ended: remember the attempt, restart the segment: both
    agents' start states, and the DS windows (B back to 1 for the new goal)."""
    history = state.history
    if state.X_human_start is not None and state.X_human_last is not None:
        history = history.add(state.X_human_start, state.X_human_last)
    return replace(
        state,
        history=history,
        X_start=state.X_current,
        X_human_start=state.X_human_last,
        filter=arbiter.initial_state(6 + state.X_current.n_fingers),
    )
