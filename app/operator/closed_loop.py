"""A simulated person who watches the robot and steers it: the closed-loop operator.

One model for the planar study and the 6-D + fingers demo, for a batch of N operators at
once (pure numpy, no clock, seeded). docs/operator.md says where each mechanism comes from;
they were chosen before any S vs DS result was seen and are not tuned to a mode.

The operator holds an *intention*: a sequence of stages, each a pose it wants the **robot**
to reach (its own target: the true goal, its own approach and grasp heading, its finger
state) with a tolerance; the last stage's tolerance is the operator's own satisfaction. It
moves its hand with the rate mapping of the loop (the robot moves as the hand moves, less
what the arbitration takes), in discrete submovements:

    perceive   the robot's pose as it was `delay + world.delay_s` ago (its own visual
               feedback delay, 0.15-0.3 s, plus the teleoperation link's image delay), with
               errors: in position a misjudgement drawn once per person (a still scene looks
               the same at every look), anisotropic through the one camera:
               `world.depth_sigma_m` along its viewing axis, `world.lateral_sigma_m` across
               it, plus a reading noise of `world.lateral_sigma_m` per axis at each look; a
               degree or two in orientation at each look
    plan       at the end of a dwell: the error e = diff(stage target, perceived robot);
               the next submovement moves the hand by gain * e (the orientation part only
               once the position is within `turn_within_m` of the stage target: the heading
               turns late), plus endpoint noise proportional to its amplitude
               (signal-dependent noise); duration by Fitts' law, a + b log2(1 + A / W), and
               never faster than the speed caps
    move       a minimum-jerk profile from the hand's pose to its submovement target,
               ballistic: the hand does not react during a submovement
    dwell      after each submovement: the perception delay plus a decision time, before
               the next plan (intermittent control); through a delayed link it also waits
               the round trip 2 world.delay_s for the movement's effect (move and wait)
    resist     if the robot moved less than half of what the last submovement asked (as
               perceived, in a group where what was asked exceeds three times the
               perception noise: a smaller lag cannot be seen), the operator pushes harder:
               the gain grows by 1.5x, up to 3x; after three resisted submovements in a
               row it pauses (0.5-1.5 s), then retries at gain 1
    clutch     a finger already fully open cannot open the robot's further (the rate
               mapping): the person closes it fully, then opens it again
    settle     a person whose own preference the robot resists settles for the task: at
               a resistance pause, a row whose intention has `settle_targets` replaces its
               targets and tolerances by those (the task's goal and success tolerance, or
               the robot's way of doing it) for the rest of the trial; which pause is the
               row's `settle_after` (1: the first, the default; a person who adapts with
               probability alpha at each disagreement, Nikolaidis et al.'s bounded-memory
               adaptation model, settles after a geometric number of pauses, and one that
               never adapts keeps its own way until its patience runs out)
    change     a person may change its mind once: at its row's `change_at_s`, its targets
               (and what it would settle for) become `change_targets` (`change_settle`)
               from its next plan on; a submovement under way is finished (ballistic), the
               stage it is in is kept (the objects world, docs/operator.md)
    satisfied  within the final stage's tolerance, it holds still; satisfied for `hold_s`
               in a row, it commits (grasps: `committed`) and is done
    patience   after `patience_s` without being done, it gives up and holds still (at
               once, even mid-movement)

Seeded: a run is the same for a seed on one machine (every random draw comes from one
generator per operator row, drawn in a fixed order).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.operator.person import Intention, OperatorProfile, put_rows
from dsteleop.app.operator.world import Impairments
from dsteleop.arbitration.se3 import FING, ROT, TRANS, HandState, diff, integrate, so3_exp
from dsteleop.errors import ContractError

Array = NDArray[np.float64]
Interval = tuple[float, float]


@dataclass
class _Rows:
    """Per-operator state (arrays of N rows)."""

    hand: HandState
    sub_from: HandState  # submovement start pose
    sub_delta: Array  # (N, D) the submovement's displacement (rotation vector in base frame)
    sub_t0: Array
    sub_T: Array
    moving: NDArray[np.bool_]
    dwell_until: Array
    stage: NDArray[np.int64]
    gain: Array
    resisted: NDArray[np.int64]
    asked: Array  # (N, D) the robot displacement the last submovement asked for
    seen_at_plan: HandState  # the perceived robot when it was planned
    planned: NDArray[np.bool_]
    satisfied_since: Array
    done: NDArray[np.bool_]
    gave_up: NDArray[np.bool_]
    settled: NDArray[np.bool_]
    changed: NDArray[np.bool_]  # changed its mind (its intention's change applied)
    pauses: NDArray[np.int64]  # resistance pauses so far
    t_done: Array
    delay: Array
    decision: Array
    seed_rows: NDArray[np.int64]


@dataclass
class ClosedLoopOperator:
    """N operators (module docstring). Call `observe(t, robot)` with every robot state and
    `hand(t)` for the hand at t; times increase.

    Args:
        intention: what each wants.
        start: the hands' starting poses (N,), where the robot starts.
        profile: the person.
        rngs: one generator per operator row (seeded by the caller).
        t0_s: the start time [s].
        world: the impairments it works under (`Impairments`: the image delay and the single
            view's perception noise are the operator's; the command delay and the goal noise
            are the caller's to apply).
    """

    intention: Intention
    start: HandState
    profile: OperatorProfile
    rngs: list[np.random.Generator]
    t0_s: float = 0.0
    world: Impairments = field(default_factory=Impairments)
    _rows: _Rows = field(init=False)
    _seen: _Seen = field(init=False)
    _draws: _Draws = field(init=False)
    _view: Array = field(init=False)  # the camera's unit viewing axis, base frame
    _misjudged: Array = field(init=False)  # (N, 3) each person's position misjudgement [m]

    def __post_init__(self) -> None:
        N = self.start.position.shape[0]
        if len(self.rngs) != N:
            raise ContractError(f"{len(self.rngs)} generators for {N} operators")
        pr = self.profile
        delay = np.array([_pick(pr.delay_s, g) for g in self.rngs])
        decision = np.array([_pick(pr.decision_s, g) for g in self.rngs])
        misjudged = np.stack([g.standard_normal(3) for g in self.rngs]) if N else np.zeros((0, 3))
        D = 6 + self.start.n_fingers
        # Enough observations for the longest delay at up to 60 Hz, and a margin.
        look_back_s = pr.delay_s[1] + self.world.delay_s
        self._seen = _Seen.empty(self.start, capacity=96 + math.ceil(60.0 * look_back_s))
        axis = np.asarray(self.world.view_axis, dtype=np.float64)
        self._view = axis / np.linalg.norm(axis)
        self._misjudged = self._position_noise(misjudged)
        self._draws = _Draws(self.rngs, 2 * D + 1)  # perception, endpoint, pause
        self._rows = _Rows(
            hand=self.start,
            sub_from=self.start,
            sub_delta=np.zeros((N, D)),
            sub_t0=np.full(N, self.t0_s),
            sub_T=np.ones(N),
            moving=np.zeros(N, dtype=bool),
            # A reaction time before the first move (it sees the robot through the link).
            dwell_until=self.t0_s + delay + self.world.delay_s + decision,
            stage=np.zeros(N, dtype=np.int64),
            gain=np.ones(N),
            resisted=np.zeros(N, dtype=np.int64),
            asked=np.zeros((N, D)),
            seen_at_plan=self.start,
            planned=np.zeros(N, dtype=bool),
            satisfied_since=np.full(N, np.nan),
            done=np.zeros(N, dtype=bool),
            gave_up=np.zeros(N, dtype=bool),
            settled=np.zeros(N, dtype=bool),
            changed=np.zeros(N, dtype=bool),
            pauses=np.zeros(N, dtype=np.int64),
            t_done=np.full(N, np.nan),
            delay=delay,
            decision=decision,
            seed_rows=np.arange(N),
        )

    # --- what the caller reads -------------------------------------------------------------

    @property
    def done(self) -> NDArray[np.bool_]:
        """(N,) finished: satisfied and held, or gave up."""
        return self._rows.done

    @property
    def gave_up(self) -> NDArray[np.bool_]:
        return self._rows.gave_up

    @property
    def committed(self) -> NDArray[np.bool_]:
        """(N,) done by committing (satisfied and held: the grasp), not by giving up."""
        return self._rows.done & ~self._rows.gave_up

    @property
    def settled(self) -> NDArray[np.bool_]:
        """(N,) settled for the task's goal and tolerance after resistance."""
        return self._rows.settled

    @property
    def changed(self) -> NDArray[np.bool_]:
        """(N,) changed its mind (`Intention.change_at_s`)."""
        return self._rows.changed

    @property
    def pauses(self) -> NDArray[np.int64]:
        """(N,) resistance pauses each row has made (counted where it can settle)."""
        return self._rows.pauses

    @property
    def t_done(self) -> Array:
        """(N,) when each finished [s] (NaN while working)."""
        return self._rows.t_done

    @property
    def stage(self) -> NDArray[np.int64]:
        return self._rows.stage

    @property
    def current(self) -> HandState:
        """(N,) the hands as last computed."""
        return self._rows.hand

    # --- the loop -------------------------------------------------------------------------

    def observe(self, t_s: float, robot: HandState) -> None:
        """The robot's state at time t (N,): what the operator will see `delay` later."""
        self._seen.add(float(t_s), robot)

    def hand(self, t_s: float) -> HandState:
        """The hands at time t (N,), after the operators planned what is due."""
        r = self._rows
        self._move(t_s)
        change = self.intention.change_at_s
        if change is not None:  # a change of mind: the new targets from the next plan on
            now = np.flatnonzero(~r.changed & ~r.done & (t_s >= change - 1e-9))
            if now.size:
                self.intention = self.intention.changed(now)
                r.changed[now] = True
        # Out of patience: it stops where its hand is, even mid-movement.
        out = ~r.done & (t_s - self.t0_s >= self.profile.patience_s - 1e-9)
        if out.any():
            r.moving[out] = False
            r.done[out] = True
            r.gave_up[out] = True
            r.t_done[out] = t_s
        due = ~r.moving & ~r.done & (t_s >= r.dwell_until - 1e-9)
        if due.any() and self._seen.count:
            self._plan(np.flatnonzero(due), t_s)  # a new submovement starts where the hand is
        return r.hand

    def select(self, keep: NDArray[np.bool_]) -> None:
        """Keep only the rows `keep` (the others' trials ended)."""
        r = self._rows
        for name, value in list(vars(r).items()):
            setattr(r, name, value.take(keep) if isinstance(value, HandState) else value[keep])
        self.intention = self.intention.take(keep)
        self._misjudged = self._misjudged[keep]
        self.rngs = [g for g, k in zip(self.rngs, keep) if k]
        self._seen.select(keep)
        self._draws.select(keep, self.rngs)

    # --- inside ---------------------------------------------------------------------------

    def _move(self, t_s: float) -> None:
        """The hands of moving rows at t: minimum-jerk along each submovement."""
        r = self._rows
        m = np.flatnonzero(r.moving)
        if m.size == 0:
            return
        u = np.clip((t_s - r.sub_t0[m]) / r.sub_T[m], 0.0, 1.0)
        s = (u * u * u * (10.0 + u * (-15.0 + 6.0 * u)))[:, None]
        # The start pose moved by the share s of the displacement: p + s dp, exp(s dw) R,
        # clip(g + s dg, 0, 1), which is eq (2)'s integration of s delta for 1 s.
        moved = integrate(r.sub_from.take(m), s * r.sub_delta[m], 1.0)
        r.hand = put_rows(r.hand, m, moved)
        ended = m[u >= 1.0]
        if ended.size:
            r.moving[ended] = False
            r.dwell_until[ended] = t_s + self._wait_s(ended)

    def _wait_s(self, idx: NDArray[np.intp]) -> Array:
        """The dwell after a submovement [s]: its own delay and decision, and the link's
        round trip (move and wait: Ferrell 1965)."""
        r = self._rows
        return r.delay[idx] + r.decision[idx] + 2.0 * self.world.delay_s

    @property
    def misjudged(self) -> Array:
        """(N, 3) each person's persistent misjudgement of the robot's position [m]."""
        return self._misjudged

    def _position_noise(self, z: Array) -> Array:
        """Position misjudgements from standard normal draws z (n, 3): sd `depth_sigma_m`
        along the view axis, `lateral_sigma_m` across it."""
        w, a = self.world, self._view
        along = z @ a
        return np.asarray(
            w.lateral_sigma_m * z + (w.depth_sigma_m - w.lateral_sigma_m) * along[:, None] * a
        )

    def _perceived(self, idx: NDArray[np.intp], t_s: float, noise: Array) -> HandState:
        """What rows `idx` see of the robot now: its state `delay + world.delay_s` ago, with
        noise (the rows' standard normal draws, (len(idx), D))."""
        r, pr = self._rows, self.profile
        pos, rot, opn = self._seen.at(idx, t_s - r.delay[idx] - self.world.delay_s)
        pos = pos + self._misjudged[idx] + self.world.lateral_sigma_m * noise[:, :3]
        rot = so3_exp(pr.angle_noise_rad * noise[:, 3:6]) @ rot
        opn = np.clip(opn + pr.openness_noise * noise[:, 6:], 0.0, 1.0)
        return HandState(pos, rot, opn)

    def _stage_errors(
        self, idx: NDArray[np.intp], seen: HandState, target: HandState
    ) -> tuple[Array, Array]:
        """Rows idx's errors to every stage `target` (n, S): (norms (n, S, 3): position,
        angle, openness; the masked differences target - seen (n, S, D))."""
        it = self.intention
        now = HandState(seen.position[:, None], seen.rotation[:, None], seen.openness[:, None])
        e = diff(target, now) * it.mask[idx]
        err = np.stack(
            [
                np.linalg.norm(e[..., TRANS], axis=-1),
                np.linalg.norm(e[..., ROT], axis=-1),
                np.abs(e[..., FING]).max(axis=-1, initial=0.0),
            ],
            -1,
        )
        return err, e

    def _plan(self, idx: NDArray[np.intp], t_s: float) -> None:
        r, pr, it = self._rows, self.profile, self.intention
        D = r.sub_delta.shape[1]
        draws = self._draws.next(idx)  # one row of draws per plan, whatever it needs
        seen = self._perceived(idx, t_s, draws[:, :D])
        last = it.n_stages[idx] - 1
        targets, tols = it.of_rows(idx, r.settled[idx])
        errs, es = self._stage_errors(idx, seen, targets)
        within_all = np.asarray((errs <= tols).all(axis=-1), dtype=np.bool_)  # (n, S)
        n = np.arange(idx.size)
        st = r.stage[idx]
        # Stages passed at once are skipped in the same plan; so is a stage whose next one
        # the robot already meets (a person who sees the robot already where the next stage
        # wants it, because the robot did that part itself, moves on).
        for _ in range(within_all.shape[1]):
            nxt = np.minimum(st + 1, last)
            advance = (st < last) & (within_all[n, st] | within_all[n, nxt])
            if not advance.any():
                break
            st = st + advance
        r.stage[idx] = st
        err, tol, e = errs[n, st], tols[n, st], es[n, st]
        within = within_all[n, st]
        final = st >= last
        # Satisfaction and patience.
        ok = within & final
        since = r.satisfied_since[idx]
        since = np.where(ok, np.where(np.isnan(since), t_s, since), np.nan)
        r.satisfied_since[idx] = since
        finished = ok & (t_s - since >= pr.hold_s - 1e-9)
        impatient = ~finished & (t_s - self.t0_s >= pr.patience_s)
        ended = idx[finished | impatient]
        r.done[ended] = True
        r.t_done[ended] = t_s
        r.gave_up[idx[impatient]] = True
        # Resistance: did the robot move as far as the last submovement asked? Judged per
        # group, where the movement asked for was large enough to see the robot lag.
        was = r.planned[idx]
        asked = r.asked[idx]
        moved = diff(seen, r.seen_at_plan.take(idx))
        lagging = np.zeros(idx.size, dtype=bool)
        # (A persistent misjudgement does not hide motion: the look-to-look noise does.)
        look_sd = (self.world.lateral_sigma_m, pr.angle_noise_rad, pr.openness_noise)
        for g, sd in zip((TRANS, ROT, FING), look_sd, strict=True):
            a, m = asked[:, g], moved[:, g]
            if a.shape[1] == 0:
                continue
            amount = np.sqrt((a * a).sum(1))
            seen_it = amount > pr.detect_k * max(sd, 1e-9)
            progress = (m * a).sum(1) / np.maximum(amount * amount, 1e-18)
            lagging |= seen_it & (progress < pr.resisted_below)
        resisted = was & ~ok & lagging
        r.resisted[idx] = np.where(resisted, r.resisted[idx] + 1, 0)
        r.gain[idx] = np.where(
            resisted, np.minimum(r.gain[idx] * pr.push_gain_step, pr.push_gain_max), 1.0
        )
        pausing = resisted & (r.resisted[idx] >= pr.resisted_before_pause)
        # Who moves now: not done, not satisfied (holds), not pausing.
        go = ~r.done[idx] & ~ok & ~pausing
        hold = ~r.done[idx] & ok
        lo, hi = pr.pause_s
        pause = lo + (hi - lo) * _uniform(draws[:, 2 * D])
        r.dwell_until[idx[hold]] = t_s + pr.hold_s / 4
        r.dwell_until[idx[pausing]] = t_s + pause[pausing]
        r.resisted[idx[pausing]] = 0
        r.gain[idx[pausing]] = 1.0
        if it.settle_targets is not None:  # resisted: it settles, at its own pause
            p_idx = idx[pausing]
            r.pauses[p_idx] += 1
            after = 1 if it.settle_after is None else it.settle_after[p_idx]
            r.settled[p_idx] |= r.pauses[p_idx] >= after
        r.planned[idx] = False
        if not go.any():
            return
        g_idx, sel = idx[go], np.flatnonzero(go)
        delta = e[sel] * r.gain[g_idx][:, None]
        far = err[sel, 0] > it.turn_within_m[g_idx]
        delta[far, 3:6] = 0.0  # the orientation turns only near the target
        # Clutching: a hand already open cannot open the robot's fingers further under the
        # rate mapping; the person closes it fully first, then opens it again (next plan).
        if D > 6:
            g_open = r.hand.openness[g_idx]
            lacking = e[sel][:, FING] > tol[sel, 2:3]  # the robot's finger is not open enough
            stuck = lacking & (g_open + delta[:, FING] > 1.0 + 1e-6) & (g_open > 0.9)
            if stuck.any():
                delta[:, FING] = np.where(stuck, -g_open, delta[:, FING])
        amp = np.stack(
            [
                np.linalg.norm(delta[:, TRANS], axis=1),
                np.linalg.norm(delta[:, ROT], axis=1),
                np.abs(delta[:, FING]).max(axis=1, initial=0.0),
            ],
            -1,
        )
        # Endpoint noise in the dimensions the person works in at all (any stage's mask):
        # a planar task's hand stays in its plane.
        noise = draws[sel, D : 2 * D] * it.mask[g_idx].max(axis=1)
        scale = np.concatenate(
            [
                np.repeat(amp[:, :1], 3, axis=1),
                np.repeat(amp[:, 1:2], 3, axis=1),
                np.repeat(amp[:, 2:], D - 6, axis=1),
            ],
            axis=1,
        )
        delta = delta + pr.endpoint_noise * scale * noise
        amp = np.stack(
            [
                np.linalg.norm(delta[:, TRANS], axis=1),
                np.linalg.norm(delta[:, ROT], axis=1),
                np.abs(delta[:, FING]).max(axis=1, initial=0.0),
            ],
            -1,
        )
        # Duration: Fitts' law on each group's amplitude over its tolerance, and the caps.
        tol = np.maximum(tol[sel], 1e-6)
        fitts = pr.fitts_a_s + pr.fitts_b_s * np.log2(1.0 + amp / tol)
        caps = 1.875 * amp / np.array([pr.v_cap_mps, pr.w_cap_radps, pr.g_cap_per_s])
        T = np.maximum(np.maximum(fitts.max(axis=1), caps.max(axis=1)), pr.min_move_s)
        r.sub_from = put_rows(r.sub_from, g_idx, r.hand.take(g_idx))
        r.sub_delta[g_idx] = delta
        r.sub_t0[g_idx] = t_s
        r.sub_T[g_idx] = T
        r.moving[g_idx] = True
        r.asked[g_idx] = delta
        r.seen_at_plan = put_rows(r.seen_at_plan, g_idx, seen.take(sel))
        r.planned[g_idx] = True


def _pick(iv: Interval, g: np.random.Generator) -> float:
    return float(iv[0] + (iv[1] - iv[0]) * g.random())


def _uniform(z: Array) -> Array:
    """Standard normal draws mapped to U(0, 1) (the normal's CDF)."""
    from scipy.special import ndtr

    return np.asarray(ndtr(z))


@dataclass
class _Draws:
    """Each row's random draws, in blocks from its own generator: a row's sequence does not
    depend on the batch it is in (so results do not depend on chunking)."""

    rngs: list[np.random.Generator]
    width: int
    block: int = 64
    _buf: Array = field(init=False)
    _used: NDArray[np.int64] = field(init=False)

    def __post_init__(self) -> None:
        self._buf = np.stack([g.standard_normal((self.block, self.width)) for g in self.rngs])
        self._used = np.zeros(len(self.rngs), dtype=np.int64)

    def next(self, idx: NDArray[np.intp]) -> Array:
        """The next row of draws of each of rows idx, (len(idx), width)."""
        full = idx[self._used[idx] >= self.block]
        for i in full:
            self._buf[i] = self.rngs[i].standard_normal((self.block, self.width))
            self._used[i] = 0
        out = self._buf[idx, self._used[idx]]
        self._used[idx] += 1
        return out

    def select(self, keep: NDArray[np.bool_], rngs: list[np.random.Generator]) -> None:
        self.rngs, self._buf, self._used = rngs, self._buf[keep], self._used[keep]


@dataclass
class _Seen:
    """The robot states observed, a ring of the last `capacity` (time-ordered)."""

    times: Array
    pos: Array
    rot: Array
    opn: Array
    count: int = 0

    @classmethod
    def empty(cls, like: HandState, capacity: int = 96) -> _Seen:
        """No observations yet, room for `capacity` (the oldest are overwritten)."""
        N, F = like.position.shape[0], like.n_fingers
        return cls(
            np.full(capacity, -np.inf), np.zeros((capacity, N, 3)),
            np.zeros((capacity, N, 3, 3)), np.zeros((capacity, N, F)),
        )  # fmt: skip

    def add(self, t_s: float, X: HandState) -> None:
        C = self.times.shape[0]
        if self.count and t_s < self.times[(self.count - 1) % C]:
            raise ContractError("observations must come in time order")
        k = self.count % C
        self.times[k] = t_s
        self.pos[k], self.rot[k], self.opn[k] = X.position, X.rotation, X.openness
        self.count += 1

    def at(self, idx: NDArray[np.intp], t_s: Array) -> tuple[Array, Array, Array]:
        """Rows idx as observed last at or before times t_s (the oldest kept if none)."""
        C = self.times.shape[0]
        n = min(self.count, C)
        order = (self.count - n + np.arange(n)) % C
        k = np.searchsorted(self.times[order], t_s + 1e-9, side="right") - 1
        slots = order[np.clip(k, 0, n - 1)]
        return self.pos[slots, idx], self.rot[slots, idx], self.opn[slots, idx]

    def select(self, keep: NDArray[np.bool_]) -> None:
        self.pos, self.rot, self.opn = self.pos[:, keep], self.rot[:, keep], self.opn[:, keep]
