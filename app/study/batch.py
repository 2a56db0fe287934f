"""The study's batched simulation: every mode of the study on a chunk of trajectories, in one
batch, tick by tick; pure, no I/O, no clock.

The batch holds one row per (mode, trajectory), row j = c N + n: trajectory n under mode c.
Every mode sees the same operator (the closed-loop operators of one trajectory are copies
with the same seed, `app.study.planar.closed_operator`) and the same goal noise, and one
arbiter steps the mixed batch (`RowModes`). The hands come from a `_Hands` source: the
open-loop operator's precomputed trajectory, or closed-loop operators who watch the robot
through the link's delay. Rows whose trial has ended leave the batch every `_CHECK_TICKS`
ticks (the arbitration is row-wise: this changes no result, only the work). States and
actions are recorded time-major on a `_Tape`; each mode's metrics are then taken over whole
arrays (`app.study.results.mode_result`). A person's later runs get eq (6)'s history term
from its earlier runs in that mode (`_history`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.operator.closed_loop import ClosedLoopOperator
from dsteleop.app.operator.open_loop import stack
from dsteleop.app.operator.world import CommandDelay
from dsteleop.app.session.trace import Trace
from dsteleop.app.study.inference import ObjectRows, ObjectRuns, RowBeliefs, draw_runs, map_stats
from dsteleop.app.study.planar import (
    Array,
    SimConfig,
    closed_operator,
    heading_of,
    hist_ranges,
    planar_state,
    robot_goal,
    sample_closed_trial,
    sample_trial,
)
from dsteleop.app.study.results import (
    ChunkResult,
    ModeResult,
    concat_results,
    mode_result,
    take_rows,
)
from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationInput,
    ArbitrationStep,
    HandState,
    Mode,
    RowModes,
    dim_names,
    make_arbiter,
)
from dsteleop.arbitration.history import history_terms
from dsteleop.arbitration.se3 import stack as stack_states
from dsteleop.errors import ContractError
from dsteleop.robot.task import Phase


def run_chunk(
    cfg: SimConfig, indices: Sequence[int], on_progress: Callable[[int], None] | None = None
) -> ChunkResult:
    """Sample trajectories `indices` and run them under every mode of `cfg`, in one batch.

    The batch holds one row per (mode, trajectory): every mode sees the same operator (the
    closed-loop operators of one trajectory are copies with the same seed) and the same goal
    noise, and the operators, the bookkeeping and the metrics are stepped once for all modes.

    Modes that run with their own arbitration (`SimConfig.mode_arbitration`) are simulated
    in a batch per configuration, each on the same people (a person's draws depend on its
    seed alone), and their results joined in the study's mode order.

    Args:
        cfg: the study.
        indices: trajectory indices.
        on_progress: called with counts of trajectory-modes done (for a progress bar).
    """
    groups = cfg.mode_groups()
    if len(groups) == 1 and groups[0][0] == cfg.arbitration:
        return _run_chunk(cfg, indices, on_progress)
    parts = [
        _run_chunk(
            dataclasses.replace(cfg, arbitration=arb, modes=modes, mode_arbitration=()),
            indices,
            on_progress,
        )
        for arb, modes in groups
    ]
    joined = {k: v for p in parts for k, v in p.modes.items()}
    modes = {m.value: joined[m.value] for m in cfg.modes}
    first = modes[cfg.modes[0].value]
    idx, lead = parts[0].indices, parts[0].lead
    return ChunkResult(idx, first.lengths, lead, first.hand_hist, first.hand_paths, modes)


def _run_chunk(
    cfg: SimConfig, indices: Sequence[int], on_progress: Callable[[int], None] | None = None
) -> ChunkResult:
    """`run_chunk` for a study whose modes share one arbitration (`cfg.arbitration`)."""
    idx = np.asarray(indices, dtype=np.int64)
    ranges = hist_ranges(cfg)
    n_paths = int(np.clip(cfg.max_paths - idx[0], 0, len(idx))) if len(idx) else 0
    C, N, A = len(cfg.modes), len(idx), cfg.runs
    runs: list[dict[str, ModeResult]] = []
    history: Array | None = None
    terminals: list[Array] = []  # per run, the hands' final (x, y, heading), (C N, 3)
    tape: _Tape | None = None  # one recording for every run (its pages are touched once)
    for a in range(A):
        goals, lead, hands = _hands_for(cfg, idx, C, a)
        tape = _Tape(hands.T, C * N) if tape is None else tape
        runs.append(
            _run_modes(
                cfg, cfg.modes, hands, goals, ranges, n_paths if a == 0 else 0, on_progress,
                history, a, tape,
            )
        )  # fmt: skip
        if a + 1 < A:  # eq (6)'s last term for the next run: this person's runs so far
            terminals.append(np.concatenate([runs[a][m.value].hand_final for m in cfg.modes]))
            history = _history(cfg, np.stack(terminals, 1))
    # Row n * A + a: run a of trajectory n (so chunks concatenate in trajectory order).
    order = np.arange(N * A).reshape(A, N).T.ravel()
    modes = {
        m.value: take_rows(concat_results([r[m.value] for r in runs]), order) for m in cfg.modes
    }
    first = modes[cfg.modes[0].value]
    return ChunkResult(idx, first.lengths, lead, first.hand_hist, first.hand_paths, modes)


def _history(cfg: SimConfig, terminals: Array) -> Array:
    """Eq (6)'s history term per row (R, 6) from the rows' previous runs: their hands'
    final planar poses (R, A, 3); every run starts at the start pose."""
    R, A = terminals.shape[:2]
    sx, sy = cfg.start_xy_m
    h0 = cfg.start_heading
    starts = planar_state(np.full((R, A), sx), np.full((R, A), sy), np.full((R, A), h0))
    ends = planar_state(terminals[..., 0], terminals[..., 1], terminals[..., 2])
    return history_terms(starts, ends, cfg.arbitration.still_offset(0))


def _hands_for(
    cfg: SimConfig, idx: NDArray[np.int64], copies: int, attempt: int = 0
) -> tuple[Array | ObjectRuns, NDArray[np.bool_], _Hands]:
    """The robot goals (N, 3) (in the objects world the run's objects, `ObjectRuns`: the
    robot infers its goal among them), lead flags (N,) and the hands of `copies` x N rows
    (one block of N per mode) of trajectories `idx`, in run `attempt`."""
    if cfg.closed_loop:
        closed = [sample_closed_trial(cfg, int(i)) for i in idx]
        goals: Array | ObjectRuns
        if cfg.objects is None:
            goals = np.stack([robot_goal(cfg, int(i), attempt) for i in idx])
            runs = None
        else:
            goals = runs = draw_runs(
                cfg.objects, cfg.seed, idx, attempt, cfg.handle_xy_m, cfg.handle_normal_rad,
                cfg.world.view_axis, cfg.world.goal_sigma_m,
            )  # fmt: skip
        lead = np.array([t.lead for t in closed], dtype=bool)
        delay = round(cfg.world.delay_s / cfg.dt_s)
        settle = delay + round(cfg.grasp_s / cfg.dt_s)
        T = round(cfg.max_trial_s / cfg.dt_s) + 1 + settle
        op = closed_operator(cfg, closed * copies, attempt, runs)
        return goals, lead, _ClosedHands(op, T, delay, settle)
    trials = [sample_trial(cfg, int(i)) for i in idx]
    stacked, lengths = stack([t.operator for t in trials])
    goals = np.stack([t.robot_goal for t in trials])
    lead = np.array([t.lead for t in trials], dtype=bool)
    return goals, lead, _OpenHands(_time_major(stacked), lengths, copies)


@dataclass(frozen=True)
class Example:
    """One trajectory under one mode, every tick kept (the per-trajectory figures).

    Attributes:
        trace: the ticks as a replay trace: T = L - 1 ticks of a trial of L states (tick k
            takes the robot from state k to state k + 1, at time t_{k+1}).
        t_s: (L,) the states' times [s].
        hand: (L, 3) the hand's x, y, heading (closed loop: in this mode).
        robot: (L, 3) the robot's x, y, heading.
    """

    trace: Trace
    t_s: Array
    hand: Array
    robot: Array


def example(cfg: SimConfig, index: int, mode: Mode) -> Example:
    """Run trajectory `index` under `mode` alone (with its own arbitration) and keep every
    tick."""
    cfg = dataclasses.replace(
        cfg, arbitration=cfg.arbitration_of(mode), modes=(mode,), mode_arbitration=()
    )
    goals, _, source = _hands_for(cfg, np.array([index]), 1)
    steps: list[ArbitrationStep] = []
    if isinstance(goals, ObjectRuns):  # the goal drawn: the object the person wants
        goal = np.array([*goals.true_xy[goals.wanted[0]], goals.normal])
        beliefs = _row_beliefs(cfg, goals, 1, source.T)
        robot, L_all, hand = _simulate(cfg, (mode,), source, beliefs, record=steps)
    else:
        goal = goals[0]
        robot, L_all, hand = _simulate(cfg, (mode,), source, goals, record=steps)
    L = int(L_all[0])
    first = steps[: L - 1]
    step = ArbitrationStep(
        **{k: np.stack([getattr(s, k)[0] for s in first]) for k in STEP_ARRAYS},
        X_next=stack_states([s.X_next.take(0) for s in first]),
    )
    t = np.arange(L, dtype=np.float64) * np.float64(cfg.dt_s)
    tr = Trace(
        name=f"trajectory {index}",
        mode=mode,
        dims=dim_names(0),
        t_s=t[1:],
        arbitrated=np.ones(L - 1, dtype=bool),
        step=step,
        p_human=np.concatenate([hand[1:L, 0, :2], np.zeros((L - 1, 1))], -1),
        p_robot=np.concatenate([robot[1:L, 0, :2], np.zeros((L - 1, 1))], -1),
        p_goal=np.tile([*goal[:2], 0.0], (L - 1, 1)),
        phases=(Phase.PICK,) * (L - 1),
        outcome=None,
        time_s=float((L - 1) * cfg.dt_s),
        v_max=cfg.arbitration.v_max(0),
    )
    return Example(tr, t, hand[:L, 0], robot[:L, 0])


def trace(cfg: SimConfig, index: int, mode: Mode) -> Trace:
    """Run one trajectory under one mode and keep every tick (`Example.trace`)."""
    return example(cfg, index, mode).trace


class _Hands:
    """Where a simulation's hands come from, tick by tick (open or closed loop), for C x N
    rows: C copies (one per mode) of N trajectories, row j = c N + n."""

    T: int  # the most states a trial can have
    lengths: NDArray[np.int64]  # (C N,) states of each trial (closed loop: T until it ends)
    gave_up: NDArray[np.bool_]  # (C N,) the operator gave up (closed loop)
    committed: NDArray[np.bool_]  # (C N,) the operator committed (open loop: all)
    settled: NDArray[np.bool_]  # (C N,) the operator settled (closed loop)
    changed: NDArray[np.bool_]  # (C N,) the operator changed its mind (closed loop)

    def start(self) -> HandState:
        raise NotImplementedError

    def next(self, k: int, t_s: float) -> tuple[HandState, HandState]:
        """(hand at state k + 1, hand at state k) of the current rows."""
        raise NotImplementedError

    def observe(self, t_s: float, X: HandState) -> None:
        """The robot at t_s (closed loop: what the operators see, later)."""

    def ended(self, rows: NDArray[np.int64], k: int) -> None:
        """Record which of `rows` ended their trial at state k + 1."""

    def keep(self, keep: NDArray[np.bool_], k: int) -> None:
        """Only the current rows `keep` go on after tick k."""
        raise NotImplementedError


class _OpenHands(_Hands):
    """Precomputed hands, time-major (T, N, ...): the operator does not watch; every copy
    reads the same trajectory."""

    def __init__(self, hands_tm: HandState, lengths: NDArray[np.int64], copies: int) -> None:
        self.pos, self.rot, self.opn = hands_tm.position, hands_tm.rotation, hands_tm.openness
        N = lengths.shape[0]
        self.lengths = np.tile(lengths, copies)
        self.gave_up = np.zeros(copies * N, dtype=bool)
        self.committed = np.ones(copies * N, dtype=bool)
        self.settled = np.zeros(copies * N, dtype=bool)
        self.changed = np.zeros(copies * N, dtype=bool)
        self.T = int(hands_tm.position.shape[0])
        self.cols = np.tile(np.arange(N), copies)  # the trajectory of each current row

    def start(self) -> HandState:
        return self._at(0)

    def _at(self, k: int) -> HandState:
        c = self.cols
        return HandState(self.pos[k, c], self.rot[k, c], self.opn[k, c])

    def next(self, k: int, t_s: float) -> tuple[HandState, HandState]:
        return self._at(k + 1), self._at(k)

    def keep(self, keep: NDArray[np.bool_], k: int) -> None:
        self.cols = self.cols[keep]


class _ClosedHands(_Hands):
    """Hands from closed-loop operators, who watch the robot (one operator per row), as the
    robot receives them: `delay` ticks late (the command path of the teleoperation delay).
    A trial ends when its operator gives up, or `settle` ticks after it commits (the grasp
    reaches the robot and the fingers close): success is judged on that settled pose."""

    def __init__(self, op: ClosedLoopOperator, T: int, delay: int = 0, settle: int = 0) -> None:
        self.op = op
        self.T = T
        self.settle = settle
        N = op.start.position.shape[0]
        self.lengths = np.full(N, T, dtype=np.int64)
        self.gave_up = np.zeros(N, dtype=bool)  # by original row (the operator compacts)
        self.committed = np.zeros(N, dtype=bool)
        self.settled = np.zeros(N, dtype=bool)
        self.changed = np.zeros(N, dtype=bool)
        self.line = CommandDelay(op.start, delay)
        self.prev = op.start

    def start(self) -> HandState:
        return self.op.start

    def next(self, k: int, t_s: float) -> tuple[HandState, HandState]:
        H = self.line.push(self.op.hand(t_s))
        prev, self.prev = self.prev, H
        return H, prev

    def observe(self, t_s: float, X: HandState) -> None:
        self.op.observe(t_s, X)

    def ended(self, rows: NDArray[np.int64], k: int) -> None:
        newly = self.op.done & (self.lengths[rows] == self.T)
        if not newly.any():
            return
        committed = self.op.committed[newly]
        ended = rows[newly]
        self.lengths[ended] = np.minimum(k + 2 + np.where(committed, self.settle, 0), self.T - 1)
        self.gave_up[ended] = self.op.gave_up[newly]
        self.committed[ended] = committed
        self.settled[ended] = self.op.settled[newly]
        self.changed[ended] = self.op.changed[newly]

    def keep(self, keep: NDArray[np.bool_], k: int) -> None:
        self.op.select(keep)
        self.line.select(keep)
        self.prev = self.prev.take(keep)


#: Ticks between the checks for ended rows in `_simulate` (the rows that ended are dropped
#: there), and the block of ticks `_Tape` buffers between two of them.
_CHECK_TICKS = 16


def _planar_into(out: Array, X: HandState) -> None:
    """Write the states X (n,) as planar poses into out (n, 3): x, y, heading."""
    out[:, :2] = X.position[:, :2]
    out[:, 2] = heading_of(X.rotation)


def _rows_of(a: Array) -> NDArray[np.void]:
    """(..., J, w) float64 with C-contiguous rows -> (..., J) of one opaque w * 8-byte item
    per row: a row is then copied as one item (a fancy-indexed copy of rows ~3x faster)."""
    return a.view(np.dtype((np.void, a.shape[-1] * a.itemsize)))[..., 0]


class _Tape:
    """The recording of one simulation of J rows of up to T states, time-major (one
    contiguous block per tick), reusable by the next run of the same shape (a run touches
    fresh memory pages only once per chunk, not once per run).

    The current rows' ticks are buffered in a block of `_CHECK_TICKS` ticks (copied as they
    come) and scattered to their rows at once when the batch's rows change (`flush`). The
    states are uninitialised where not written: every state before a row's length is
    written (a row leaves the batch only after its trial ended) and `_simulate` sets the rest
    to NaN. The actions start at zero and count only where `acted` (set by `close` from the
    trials' lengths; elsewhere they hold a later tick of the row, an earlier run's finite
    values or zero).

    Attributes:
        robot, hand: (T, J, 3) x, y and heading per state.
        U_human, U_out: (T - 1, J, 6) the actions of each tick.
        acted: (T - 1, J) the tick belongs to the row's trial.
    """

    def __init__(self, T: int, J: int) -> None:
        self.shape = (T, J)
        self.robot, self.hand = np.empty((T, J, 3)), np.empty((T, J, 3))
        self.U_human, self.U_out = np.zeros((T - 1, J, 6)), np.zeros((T - 1, J, 6))
        self.acted = np.zeros((T - 1, J), dtype=bool)
        B = _CHECK_TICKS
        # The block: tick k's states (at k + 1) and actions (at k) of the current rows.
        self._block = tuple(np.empty((B, J, w)) for w in (3, 3, 6, 6))
        self._from = 0  # the block's first tick
        self._ticks = 0  # ticks in the block

    def start(self, T: int, J: int) -> _Tape:
        """Ready for a run of the same shape."""
        if (T, J) != self.shape:
            raise ContractError(f"a tape of {self.shape} for a run of {(T, J)}")
        self._from = self._ticks = 0
        return self

    def put(self, k: int, X: HandState, H: HandState, U_h: Array, U_out: Array) -> None:
        """Tick k of the current rows: the robot X and the hand H at state k + 1 and the
        actions. Ticks come in order; `flush` at least every `_CHECK_TICKS` ticks."""
        i = k - self._from
        n = U_h.shape[0]
        robot, hand, uh, uo = self._block
        _planar_into(robot[i, :n], X)
        _planar_into(hand[i, :n], H)
        uh[i, :n], uo[i, :n] = U_h, U_out
        self._ticks = i + 1

    def flush(self, rows: NDArray[np.int64]) -> None:
        """Scatter the block's ticks to `rows` (the rows they were of)."""
        k0, B, n = self._from, self._ticks, rows.size
        states = slice(k0 + 1, k0 + 1 + B)
        actions = slice(k0, k0 + B)
        targets = (
            self.robot[states],
            self.hand[states],
            self.U_human[actions],
            self.U_out[actions],
        )
        for full, block in zip(targets, self._block, strict=True):
            if n == self.shape[1]:
                full[...] = block[:B]
            else:
                _rows_of(full)[:, rows] = _rows_of(block[:B, :n])
        self._from, self._ticks = k0 + B, 0

    def close(self, lengths: NDArray[np.int64]) -> None:
        """The trials' lengths (J,) known: tick k belongs to row j's trial iff k + 1 <
        lengths[j] (a row stays in the batch at least that long)."""
        np.less(np.arange(1, self.shape[0])[:, None], lengths[None, :], out=self.acted)


def _simulate(
    cfg: SimConfig,
    modes: Sequence[Mode],
    hands: _Hands,
    goals: Array | RowBeliefs,
    record: list[ArbitrationStep] | None = None,
    on_progress: Callable[[int], None] | None = None,
    history: Array | None = None,
    tape: _Tape | None = None,
) -> tuple[Array, NDArray[np.int64], Array]:
    """Step the batch of len(modes) x N rows (row j = m N + n: trajectory n under mode m)
    through time. Returns the robot's and the hand's (x, y, heading), time-major (T, C N, 3)
    each (T: the longest trial), NaN past the end of each trial, and the trials' lengths
    (states).

    One arbiter steps the mixed batch (`RowModes`). Rows whose trial has ended are
    dropped from the batch every few ticks (the arbitration is row-wise, so this changes no
    result, only the work). The states and the actions of the rows whose trial includes a
    tick go on `tape` (a fresh one when None; the returned poses are views of it);
    on_progress is called with counts of trials that ended; `record` (one mode only) gets
    every step; `history` (C N, 6) is eq (6)'s history term of each row (None: no previous
    runs). `goals` are the robot's goals (N, 3), or (the objects world) the rows' beliefs,
    updated each tick from the hand the robot receives, which give each row's goal and the
    confidence in it.
    """
    beliefs = goals if isinstance(goals, RowBeliefs) else None
    C = len(modes)
    N = goals.ids.size // C if isinstance(goals, RowBeliefs) else goals.shape[0]
    if record is not None and C != 1:
        raise ContractError("record needs a single mode")
    T, J = hands.T, C * N
    # One arbiter steps every mode's rows at once (a mixed batch: row j is in mode j // N).
    arb = make_arbiter(modes[0], cfg.arbitration)
    mixed = RowModes.of([m for m in modes for _ in range(N)]) if C > 1 else None
    state = arb.initial_state(6, batch=(J,))
    X0 = planar_state(
        np.full(J, cfg.start_xy_m[0]), np.full(J, cfg.start_xy_m[1]), np.full(J, cfg.start_heading)
    )
    if isinstance(goals, RowBeliefs):
        G = goals.goal()
    else:
        g = np.tile(goals, (C, 1))
        G = planar_state(g[:, 0], g[:, 1], g[:, 2])
    confidence: Array | None = None
    confidence_joint: Array | None = None
    rows = np.arange(J)
    hist = history
    X, Xp, X0r = X0, X0, X0
    H0 = hands.start()
    tape = (_Tape(T, J) if tape is None else tape).start(T, J)
    _planar_into(tape.robot[0], X)
    _planar_into(tape.hand[0], H0)
    hands.observe(0.0, X)
    reported = 0
    for k in range(T - 1):
        if k % _CHECK_TICKS == 0 and k > 0:
            tape.flush(rows)
            keep = hands.lengths[rows] > k + 1
            if on_progress is not None:
                done = int(J - rows.size + np.count_nonzero(~keep))
                if done > reported:
                    on_progress(done - reported)
                    reported = done
            if not keep.any():
                break
            if keep.sum() < 0.9 * rows.size:
                rows = rows[keep]
                state = state.select(keep)
                mixed = None if mixed is None else mixed.select(keep)
                X, Xp, X0r, H0, G = (h.take(keep) for h in (X, Xp, X0r, H0, G))
                hist = None if hist is None else hist[keep]
                hands.keep(keep, k)
                if beliefs is not None:
                    beliefs.keep(keep)
        t_next = (k + 1) * cfg.dt_s
        H, Hp = hands.next(k, t_next)
        hands.ended(rows, k)
        if beliefs is not None:  # the belief from the hand's step, at the robot: its goal
            beliefs.update(k, X, H, Hp)
            G = beliefs.goal()
            confidence, confidence_joint = beliefs.confidence.per_dim, beliefs.confidence.joint
        inp = ArbitrationInput(
            X_human=H, X_human_prev=Hp, X_human_start=H0, X_current=X, X_prev=Xp, X_start=X0r,
            X_goal=G, dt=cfg.dt_s, history_term=hist, confidence=confidence,
            confidence_joint=confidence_joint,
        )  # fmt: skip
        # The study reads the actions and states only: eq (4)-(7) just where a mode's rule
        # reads them (every quantity when every step is recorded).
        state, step = arb.step(state, inp, mixed, every_quantity=record is not None)
        Xp, X = X, step.X_next
        hands.observe(t_next, X)
        tape.put(k, X, H, step.U_human, step.U_out)
        if record is not None:
            record.append(step)
    tape.flush(rows)
    if on_progress is not None and J > reported:
        on_progress(J - reported)
    lengths = np.minimum(hands.lengths, T)
    tape.close(lengths)
    T = int(lengths.max())  # the longest trial (closed loop: often far under the limit)
    past = np.arange(T)[:, None] >= lengths[None, :]

    def poses(p: Array) -> Array:
        out = p[:T]
        # Past a row's length the buffers hold whatever memory held: NaN there.
        np.copyto(out, np.nan, where=past[..., None])
        return out

    return poses(tape.robot), lengths, poses(tape.hand)


def _time_major(hands: HandState) -> HandState:
    """(N, T, ...) -> contiguous (T, N, ...) copies."""
    return HandState(
        *(
            np.ascontiguousarray(np.swapaxes(a, 0, 1))
            for a in (hands.position, hands.rotation, hands.openness)
        )
    )


def _run_modes(
    cfg: SimConfig,
    modes: Sequence[Mode],
    hands: _Hands,
    goals: Array | ObjectRuns,
    ranges: Array,
    n_paths: int,
    on_progress: Callable[[int], None] | None = None,
    history: Array | None = None,
    attempt: int = 0,
    tape: _Tape | None = None,
) -> dict[str, ModeResult]:
    """Simulate every mode in one batch (`_simulate`, recording on `tape`, a fresh one when
    None), then each mode's metrics (run `attempt`, with eq (6)'s history term `history`
    (C N, 6) per row, None for none). Every action of every trial is recorded, time-major;
    the metrics are computed afterwards over whole arrays with dsteleop.arbitration.metrics
    (the results hold no view of the tape)."""
    C = len(modes)
    runs, beliefs = None, None
    source: Array | RowBeliefs
    if isinstance(goals, ObjectRuns):
        runs, N = goals, goals.wanted.size
        source = beliefs = _row_beliefs(cfg, goals, C, hands.T)
    else:
        source, N = goals, goals.shape[0]
    J = C * N
    tape = _Tape(hands.T, J) if tape is None else tape
    poses, lengths, hand = _simulate(
        cfg, modes, hands, source, on_progress=on_progress, history=history, tape=tape
    )
    objects: ObjectRows | None = None
    if runs is not None and beliefs is not None:
        wanted = np.where(hands.changed, np.tile(runs.final, C), np.tile(runs.wanted, C))
        stats = map_stats(beliefs.map_record, lengths, wanted, cfg.dt_s)
        objects = ObjectRows(runs.true_xy, wanted, hands.changed, stats)
    U_h_all, U_out_all, acted = tape.U_human, tape.U_out, tape.acted
    h_norm = np.zeros(J) if history is None else np.abs(history).sum(-1)
    out = {}
    for c, mode in enumerate(modes):
        part = slice(c * N, (c + 1) * N)
        L = lengths[part]
        Tm = int(L.max())  # this mode's longest trial
        out[mode.value] = mode_result(
            cfg,
            poses[:Tm, part],
            L,
            hand[:Tm, part],
            hands.gave_up[part],
            hands.committed[part],
            U_h_all[: Tm - 1, part],
            U_out_all[: Tm - 1, part],
            acted[: Tm - 1, part],
            ranges,
            n_paths,
            attempt,
            h_norm[part],
            hands.settled[part],
            None if objects is None else objects.take(part),
        )
    return out


def _row_beliefs(cfg: SimConfig, runs: ObjectRuns, copies: int, ticks: int) -> RowBeliefs:
    """The beliefs of `copies` x N rows (one block of N per mode) over the objects of the
    run `runs` as the robot perceives them, with its perception error's sd as the belief's
    sigma (x, y and heading; 0 in z, roll, pitch)."""
    assert cfg.objects is not None
    p = np.tile(runs.perceived, (copies, 1, 1))  # (J, K, 3)
    goals = planar_state(p[..., 0], p[..., 1], p[..., 2])
    sd = cfg.objects.perception_sd(cfg.world.view_axis)
    sigma = np.zeros((*p.shape[:2], 6))
    sigma[..., 0], sigma[..., 1], sigma[..., 5] = sd
    return RowBeliefs(goals, sigma, cfg.arbitration.belief, ticks)
