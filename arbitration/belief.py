"""A belief over K candidate goals from the person's motion, and the robot's confidence in
each dimension of the goal it then seeks (docs/METHOD.md §10).

Candidates. Goal g (g = 1..K) is a pose in the arbitration's 6 + F dimensions, `goal_g`,
with a pose uncertainty per dimension, `sigma_g,i` (the robot's perception error of that
goal along each axis, anisotropic: a camera's depth error is larger than its lateral one),
and a prior probability `prior_g`. Every dimension i has a scale `s_i`, the tolerance the
task asks for (success radius [m], heading tolerance [rad], openness), which makes the
dimensions commensurable.

Belief (MaxEnt / Boltzmann-rational person, Dragan & Srinivasa 2013, Javdani et al.
2015/2018). The person moving from x to x' towards goal g pays the cost of the motion and
is left with the cost-to-go V_g(x'); the likelihood of that motion under goal g is
exp(-beta * (C(x, x') + V_g(x') - V_g(x))), the soft-min form of Javdani's
`ada_assistance_policy` (the log-likelihood of the action is Q_g - V_g). The motion's own
cost C is the same for every goal and cancels in the normalisation, so one tick is

    V_g(x)   = sqrt( sum_i (d_g,i(x)^2 + sigma_g,i^2) / s_i^2 ),   d_g = diff(goal_g, x)
    b'_g     = b_g * exp(-beta * (V_g(x_t) - V_g(x_{t-1}))) / Z            (Bayes' rule)
    b_g     <- eps where b'_g < eps, the others rescaled to sum to 1        (the floor)

with x -> x' the person's motion this tick, b the belief (starting at the prior) and Z the
normaliser. Which x: where the robot follows the hand exactly (manual control) the mapped hand
`X_human` is the robot, and x -> x' is the hand's own step. Under assistance the mapped hand
drifts from the robot (docs/METHOD.md §2: it integrates what the person pushed, not where it
wants the robot), and its distance to the candidates says little; the motion is then read
where it acts, as Javdani's `ada_assistance_policy` reads the user's action from the robot's
state: x = X_current, x' = `commanded(X_current, X_human, X_human_prev)`, the robot's state
moved by the hand's step (identical to the hand's own step under manual control).

V_g is the distance to the goal in units of the task's tolerances, softened by
the goal's own uncertainty (the expected squared distance to a goal known up to sigma), so
approaching an uncertain goal is weaker evidence once the hand is within its uncertainty, and
V_g is smooth at the goal. Where x' of one tick is x of the next (the hand's own path),
without the floor the log-odds telescope: log b_g(t) = log prior_g - beta (V_g(x_t) -
V_g(x_0)) + const, so tremor does not accumulate, only where the hand got to; read at the
robot's state, a person pushing against a robot that goes elsewhere keeps adding evidence
for the goals it pushes towards, and tremor adds a zero-mean walk that the floor bounds.
The floor keeps every goal's probability at eps or above (the goals below it are set to
eps, the others keep their ratios; repeated until none is below, at most K passes), as
Javdani's `ada_assistance_policy` clips its goal probabilities, against the runaway
confidence Aronson & Short warn of: the log-odds of any two goals stay within
L = log((1 - (K - 1) eps) / eps), so a person who changes their mind is followed within a
bounded time (about L / beta tolerances of progress towards the new goal). A belief within
the bound is left as it is, so a hand that holds still keeps the belief it earned (mixing with the
uniform every tick instead would fade it back to uniform in about 1 / (K eps) ticks).

Per-dimension confidence. The robot seeks the belief's MAP candidate m (ties: the first).
Its confidence in dimension i is the probability, under the belief and the goals'
uncertainties, that the true goal lies within the task's tolerance s_i of the MAP goal in
that dimension (the true goal g's coordinate ~ N(goal_g,i, sigma_g,i^2)):

    W_m,g,i = P(|delta_g,i + n| < s_i),  n ~ N(0, sigma_g,i^2),  delta_g = diff(goal_g, goal_m)
            = (erf((s_i - delta_g,i) / r) + erf((s_i + delta_g,i) / r)) / 2,  r = sqrt(2) sigma_g,i
    c_i     = sum_g b_g W_m,g,i                                               in [0, 1]

so (a) where the likely candidates agree along x (|delta_g,x| << s_x), c_x is high even if
y is undecided, and (b) a goal whose own uncertainty in i is large against s_i gives a low
c_i even when the belief is certain (c_i = erf(s_i / (sqrt 2 sigma_m,i)) then). sigma = 0 is
the indicator |delta| < s. The joint confidence, one scalar for the confidence-scaled
scalar baseline (Dragan's form), is the same probability in every dimension at once, the
axes independent: c_joint = sum_g b_g prod_i W_m,g,i. W depends only on the candidates, so
it is tabulated once (K x K x D per row of candidates) and a tick's confidence is a lookup
and a weighted sum.

Batching: the belief is (n, K), one row per arbitrated row; the candidates are shared by
every row (a batch (K,)) or one set per row (a batch (n, K)). The cost-to-go, Bayes' rule with
the floor, and the confidence are compiled loops over the rows (`arbitration/jit.py`), the
tables numpy at construction (one tick over 3 candidates for one row is tens of microseconds,
`dsteleop bench --only arbitration`; the study steps thousands of rows at once).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np
from numpy.typing import NDArray
from scipy.special import erf

from dsteleop.arbitration.jit import kernel
from dsteleop.arbitration.modes.base import check_range
from dsteleop.arbitration.se3 import HandState, diff, integrate, log_relative_of
from dsteleop.errors import ConfigError

Array = NDArray[np.float64]

NAME = "belief"


@dataclass(frozen=True)
class BeliefParams:
    """The belief's parameters (module docstring); a value out of range is a ConfigError
    naming it as `belief.<field>`.

    Attributes:
        beta: rationality, nats of evidence per tolerance of progress towards one goal
            rather than another, in (0, 100]. Default 1: Dragan & Srinivasa's MaxEnt model
            (beta absorbed in the cost, 1) with the cost in units of the task's tolerance.
        epsilon: the floor on every goal's probability, in (0, 0.25] and below 1/K (checked
            with the candidates). Default 0.01: the log-odds stay within log(98) ~ 4.6 for
            K = 3, about 5 tolerances of progress at beta = 1.
        scale_m: s of x, y, z [m], in (0, 1]. Default 0.02: the tasks' success radii (1-3 cm)
            and eq (4)'s floor `alloc_floor_m`.
        scale_rad: s of the three rotation dimensions [rad], in (0, pi]. Default 0.2: the
            heading tolerance of the tasks (about 11 deg).
        scale_openness: s of each finger's openness, in (0, 1]. Default 0.1 (eq (4)'s
            `alloc_floor_openness`).
    """

    beta: float = 1.0
    epsilon: float = 0.01
    scale_m: float = 0.02
    scale_rad: float = 0.2
    scale_openness: float = 0.1

    def __post_init__(self) -> None:
        check_range(NAME, "beta", self.beta, 0.0, 100.0)
        check_range(NAME, "epsilon", self.epsilon, 0.0, 0.25)
        check_range(NAME, "scale_m", self.scale_m, 0.0, 1.0)
        check_range(NAME, "scale_rad", self.scale_rad, 0.0, math.pi)
        check_range(NAME, "scale_openness", self.scale_openness, 0.0, 1.0)

    def scale(self, n_fingers: int) -> Array:
        """(6 + F,) the tolerance s_i of every dimension."""
        return np.concatenate(
            [
                np.full(3, self.scale_m),
                np.full(3, self.scale_rad),
                np.full(n_fingers, self.scale_openness),
            ]
        )


class Confidence(NamedTuple):
    """What the arbitration reads from a belief for one tick, per row.

    Attributes:
        map_index: (n,) the MAP candidate of each row (the robot's goal).
        per_dim: (n, 6 + F) c_i in [0, 1].
        joint: (n,) c_joint in [0, 1].
    """

    map_index: NDArray[np.intp]
    per_dim: Array
    joint: Array


@dataclass(frozen=True)
class GoalBelief:
    """K candidate goals and the belief's model over them (module docstring).

    Attributes:
        goals: the candidates' poses, a HandState of batch (K,) shared by every row, or
            (n, K), one set per row.
        sigma: the candidates' pose uncertainty per dimension, (K, 6 + F) or (n, K, 6 + F),
            >= 0 (metres, radians, openness; the rotation entries are about the base axes).
        params: the belief's parameters.
        prior: (K,) or (n, K) prior probabilities (normalised here; default uniform), > 0.
        names: one name per candidate (for messages and views), default "0".."K-1".
    """

    goals: HandState
    sigma: Array
    params: BeliefParams = field(default_factory=BeliefParams)
    prior: Array | None = None
    names: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        batch = self.goals.batch
        if len(batch) not in (1, 2) or batch[-1] < 1:
            raise ConfigError(f"belief: goals need a batch (K,) or (n, K), got {batch}")
        K, D = batch[-1], 6 + self.goals.n_fingers
        sigma = np.asarray(self.sigma, dtype=np.float64)
        if sigma.shape not in ((K, D), (*batch, D)):
            raise ConfigError(
                f"belief: sigma must be ({K}, {D}) or {(*batch, D)}, got {sigma.shape}"
            )
        if not np.isfinite(sigma).all() or (sigma < 0).any():
            raise ConfigError("belief: sigma must be finite and >= 0")
        if K * self.params.epsilon >= 1.0:
            raise ConfigError(
                f"belief.epsilon must be below 1/K = {1.0 / K:.3g} for K = {K} candidates, "
                f"got {self.params.epsilon!r}"
            )
        prior = np.full(K, 1.0 / K) if self.prior is None else np.asarray(self.prior, float)
        if prior.shape not in ((K,), batch) or not np.isfinite(prior).all() or (prior <= 0).any():
            raise ConfigError(f"belief: prior must be ({K},) or {batch}, finite and > 0")
        if self.names and len(self.names) != K:
            raise ConfigError(f"belief: {len(self.names)} names for {K} candidates")
        prior = prior / prior.sum(axis=-1, keepdims=True)
        rows = batch[0] if len(batch) == 2 else 1
        goals = self.goals if len(batch) == 2 else _with_rows(self.goals)
        sigma = np.broadcast_to(sigma, (rows, K, D))
        scale = self.params.scale(self.goals.n_fingers)
        scale.flags.writeable = False
        object.__setattr__(self, "_scale", scale)
        object.__setattr__(self, "_prior", prior)
        table = _agreement(goals, sigma, scale)
        self._derive_rows(
            goals,
            {
                "_sigma2_over_s2_sum": ((sigma / scale) ** 2).sum(-1),
                "_table": table,
                "_joint_table": table.prod(axis=3),
            },
        )

    def _derive_rows(self, goals: HandState, tables: dict[str, Array]) -> None:
        """Set what is held per row: the goals (batch (rows, K)), the same goals as the
        compiled cost takes them ((rows K, ...) C-contiguous), and `tables`, each with the
        row as its first axis (`take` selects the rows of every one of them)."""
        object.__setattr__(self, "_goals", goals)
        flat = tuple(
            np.ascontiguousarray(a.reshape(a.shape[0] * a.shape[1], *a.shape[2:]), dtype=np.float64)
            for a in (goals.position, goals.rotation, goals.openness)
        )
        object.__setattr__(self, "_flat_goals", flat)
        tables = {name: np.ascontiguousarray(value) for name, value in tables.items()}
        object.__setattr__(self, "_row_tables", tables)
        for name, value in tables.items():
            object.__setattr__(self, name, value)

    @property
    def K(self) -> int:
        return int(self.goals.batch[-1])

    @property
    def dims(self) -> int:
        return 6 + self.goals.n_fingers

    @property
    def scale(self) -> Array:
        """(6 + F,) the tolerance s_i of every dimension (read-only)."""
        scale: Array = self.__dict__["_scale"]
        return scale

    @property
    def agreement(self) -> Array:
        """(rows, K, K, 6 + F) W_m,g,i of the module docstring (rows: 1 or n)."""
        table: Array = self.__dict__["_table"]
        return table

    def candidate_index(self, name: str) -> int:
        """The index of the candidate `name`; an unknown name is a ConfigError listing them."""
        names = self.names or tuple(str(k) for k in range(self.K))
        if name not in names:
            raise ConfigError(f"unknown candidate {name!r} (candidates: {', '.join(names)})")
        return names.index(name)

    def initial(self, n: int) -> Array:
        """(n, K) the belief before any motion: the prior, floored."""
        prior = np.array(np.broadcast_to(self.__dict__["_prior"], (n, self.K)), dtype=np.float64)
        zero = np.zeros((n, self.K))
        return _update(prior, zero, zero, 0.0, float(self.params.epsilon))

    def cost_to_go(self, X: HandState) -> Array:
        """(n, K) V_g(x) of the module docstring, for the states X of batch (n,)."""
        gp, gR, gg = self.__dict__["_flat_goals"]
        xp, xR, xg = (
            np.ascontiguousarray(a, dtype=np.float64) for a in (X.position, X.rotation, X.openness)
        )
        extra: Array = self.__dict__["_sigma2_over_s2_sum"]
        if extra.shape[0] not in (1, xp.shape[0]):
            raise ConfigError(f"belief over {extra.shape[0]} rows given {xp.shape[0]} states")
        return _cost_to_go(gp, gR, gg, xp, xR, xg, extra, self.scale, self.K)

    def update(self, belief: Array, X_human: HandState, X_human_prev: HandState) -> Array:
        """One tick of Bayes' rule and the floor (module docstring): the new (n, K) belief
        after the person moved from X_human_prev to X_human (batch (n,) each)."""
        b = np.ascontiguousarray(belief, dtype=np.float64)
        if b.ndim != 2 or b.shape[1] != self.K:
            raise ConfigError(f"belief of shape {b.shape} for {self.K} candidates")
        now, before = self.cost_to_go(X_human), self.cost_to_go(X_human_prev)
        return _update(b, now, before, float(self.params.beta), float(self.params.epsilon))

    def confidence(self, belief: Array) -> Confidence:
        """The MAP candidate, c_i and c_joint of each row (module docstring)."""
        b = np.ascontiguousarray(belief, dtype=np.float64)
        table: Array = self.__dict__["_table"]
        if table.shape[0] not in (1, b.shape[0]):
            raise ConfigError(f"belief over {table.shape[0]} rows given {b.shape[0]} beliefs")
        m, per_dim, joint = _confidence(b, table, self.__dict__["_joint_table"])
        return Confidence(m, per_dim, joint)

    def goal_of(self, index: NDArray[np.intp]) -> HandState:
        """The poses (batch (n,)) of candidate `index[r]` for each row r: the robot's X_goal."""
        goals: HandState = self.__dict__["_goals"]
        idx = np.asarray(index, dtype=np.intp)
        # Row r's candidate k is row r K + k of the flattened goals (one take per array).
        flat = idx + np.arange(idx.shape[0]) * self.K if goals.batch[0] > 1 else idx
        gp, gR, gg = self.__dict__["_flat_goals"]
        return HandState(gp.take(flat, 0), gR.take(flat, 0), gg.take(flat, 0))

    def take(self, rows: NDArray[np.bool_] | NDArray[np.intp]) -> GoalBelief:
        """The model of the rows `rows` of candidates given one set per row (batch (n, K)),
        its tables taken from this one's (each row's are computed from its own candidates
        alone, so they are the ones a model of those rows computes)."""
        if len(self.goals.batch) != 2:
            raise ConfigError("belief: take needs candidates given one set per row (n, K)")
        d = self.__dict__
        sigma = np.asarray(self.sigma)
        prior = self.prior
        if prior is not None and np.ndim(prior) == 2:
            prior = np.asarray(prior)[rows]
        out = object.__new__(GoalBelief)
        fields = {
            "goals": self.goals.take(rows),
            "sigma": sigma[rows] if sigma.ndim == 3 else sigma,
            "params": self.params,
            "prior": prior,
            "names": self.names,
            "_scale": d["_scale"],
            "_prior": d["_prior"][rows] if d["_prior"].ndim == 2 else d["_prior"],
        }
        for name, value in fields.items():
            object.__setattr__(out, name, value)
        tables: dict[str, Array] = d["_row_tables"]
        out._derive_rows(d["_goals"].take(rows), {k: v[rows] for k, v in tables.items()})
        return out


@kernel
def _cost_to_go(
    gp: Array, gR: Array, gg: Array, xp: Array, xR: Array, xg: Array, extra: Array, s: Array,
    K: int,
) -> Array:  # fmt: skip
    """(n, K) V_g(x) of the module docstring: the goals (rows K, ...) flattened row-major
    (rows = 1: shared by every state), the n states, `extra` (rows, K) the sum of
    sigma^2 / s^2 over the dimensions, s (6 + F,) the tolerances."""
    n = xp.shape[0]
    shared = extra.shape[0] == 1
    out = np.empty((n, K))
    for r in range(n):
        base = 0 if shared else r
        for k in range(K):
            j = base * K + k
            sq = extra[base, k]
            for i in range(3):
                d = (gp[j, i] - xp[r, i]) / s[i]
                sq += d * d
            w0, w1, w2 = log_relative_of(gR, j, xR, r)
            sq += (w0 / s[3]) ** 2 + (w1 / s[4]) ** 2 + (w2 / s[5]) ** 2
            for f in range(gg.shape[1]):
                d = (gg[j, f] - xg[r, f]) / s[6 + f]
                sq += d * d
            out[r, k] = math.sqrt(sq)
    return out


def commanded(X_robot: HandState, X_human: HandState, X_human_prev: HandState) -> HandState:
    """Where the person's step this tick takes the robot: X_robot moved by diff(X_human,
    X_human_prev) (eq (2)'s integration of the hand's motion, from the robot's state): the x'
    of the belief's update read at the robot's state, x = X_robot (module docstring)."""
    return integrate(X_robot, diff(X_human, X_human_prev), 1.0)


@kernel
def _update(b: Array, now: Array, before: Array, beta: float, eps: float) -> Array:
    """(n, K) Bayes' rule and the floor of the module docstring for each row: b_g exp(-beta
    (now_g - before_g)) normalised (from the largest log, for range), then every b_g < eps
    set to eps and the others rescaled to keep their ratios, repeated until none is below
    (at most K passes; a row that needs none is left as it is)."""
    n, K = b.shape
    out = np.empty((n, K))
    low = np.empty(K, dtype=np.bool_)
    for r in range(n):
        top = -np.inf
        for k in range(K):
            out[r, k] = math.log(b[r, k]) - beta * (now[r, k] - before[r, k])
            top = max(top, out[r, k])
        total = 0.0
        for k in range(K):
            out[r, k] = math.exp(out[r, k] - top)
            total += out[r, k]
        for k in range(K):
            out[r, k] /= total
            low[k] = False
        for _ in range(K):  # each pass floors at least one more goal, or ends
            more = False
            for k in range(K):
                if not low[k] and out[r, k] < eps:
                    low[k] = more = True
            if not more:
                break
            n_low, rest = 0, 0.0
            for k in range(K):
                if low[k]:
                    n_low += 1
                else:
                    rest += out[r, k]
            share = (1.0 - eps * n_low) / rest
            for k in range(K):
                out[r, k] = eps if low[k] else out[r, k] * share
    return out


@kernel
def _confidence(
    b: Array, table: Array, joint_table: Array
) -> tuple[NDArray[np.intp], Array, Array]:
    """Each row's MAP m (the first largest), c_i = sum_g b_g W_m,g,i and c_joint = sum_g b_g
    prod_i W_m,g,i (clipped to [0, 1]) from the tables W (rows, K, K, D) and prod_i W (rows,
    K, K), rows = 1 (shared) or n."""
    n, K = b.shape
    D = table.shape[3]
    m_out = np.empty(n, dtype=np.intp)
    per_dim = np.zeros((n, D))
    joint = np.zeros(n)
    for r in range(n):
        t = 0 if table.shape[0] == 1 else r
        m = 0
        for k in range(1, K):
            if b[r, k] > b[r, m]:
                m = k
        m_out[r] = m
        c_joint = 0.0
        for g in range(K):
            w = b[r, g]
            c_joint += w * joint_table[t, m, g]
            for i in range(D):
                per_dim[r, i] += w * table[t, m, g, i]
        joint[r] = min(1.0, max(0.0, c_joint))
        for i in range(D):
            per_dim[r, i] = min(1.0, max(0.0, per_dim[r, i]))
    return m_out, per_dim, joint


def _with_rows(X: HandState) -> HandState:
    """A (K,) state as (1, K)."""
    return HandState(X.position[None], X.rotation[None], X.openness[None])


def _agreement(goals: HandState, sigma: Array, scale: Array) -> Array:
    """(rows, K, K, D) W_m,g,i = P(|diff(goal_g, goal_m)_i + n| < s_i), n ~ N(0, sigma_g,i^2)."""
    G_m = HandState(
        goals.position[:, :, None], goals.rotation[:, :, None], goals.openness[:, :, None]
    )
    G_g = HandState(goals.position[:, None], goals.rotation[:, None], goals.openness[:, None])
    delta = diff(G_g, G_m)  # (rows, K_m, K_g, D)
    sig = np.broadcast_to(sigma[:, None], delta.shape)
    inside = (np.abs(delta) < scale).astype(np.float64)  # sigma = 0: the indicator
    safe = np.where(sig > 0, sig, 1.0) * math.sqrt(2.0)
    smooth = 0.5 * (erf((scale - delta) / safe) + erf((scale + delta) / safe))
    out: Array = np.where(sig > 0, smooth, inside)
    return out
