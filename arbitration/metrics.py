"""Metrics of the paper's Section IV-D (docs/METHOD.md §7): pure numpy/scipy, no I/O, no clock.

Assistance quality, per action (one tick, one (6 + F) velocity vector):

    cosine distance   c = 1 - U_h . U_out / (|U_h| |U_out|)        in [0, 2]
    agreement         ag = 1 if U_h . U_out > 0 else 0
    ratio of agreement phi = sum(ag) / number of actions          in [0, 1]

The paper's cosine distance is the SUM over the actions of a trial (its headline here);
the mean per action (sum / counted actions) is reported beside it, labelled: the sum grows
with the trial's length, the mean does not.

Idle actions, treated alike by both metrics: an action where |U_h| or |U_out| is at most
`tol` (`IDLE_TOL` = 1e-9 in the actions' units, nine orders of magnitude under any velocity
limit: numerically zero) has no direction. The cosine distance is undefined there, and the
paper's `ag` would count it as disagreement (U_h . U_out = 0), so a pause of the operator, or
an output that is exactly zero (a robot parked at its goal under alpha = 1), would count
against the mode in one metric and not at all in the other. Both metrics skip exactly the
same actions (`idle_actions`), and report how many (`n_skipped`). `agreement(...,
skip_idle=False)` is the paper's literal count over every action.

McNemar's test of paired success (the same trials under two conditions; Fagerland, Lydersen
and Laake 2013): with b trials that only the first condition succeeded and c that only the
second did, under H0 X = b ~ Binomial(b + c, 1/2); with k = min(b, c), n = b + c,

    exact  p = min(1, 2 P(X <= k))
    mid-p  p = min(1, 2 P(X <= k) - P(X = k))

(p = 1 when n = 0). The concordant trials carry no information about the difference.

Success rate of s successes in n trials, with z = 1.96 for 95 %:

    Laplace estimate      p_L = (s + 1) / (n + 2)
    adjusted Wald CI      p_a = (s + z^2/2) / (n + z^2),
                          p_a -/+ z sqrt(p_a (1 - p_a) / (n + z^2)), clipped to [0, 1]

N-1 chi-squared test of two proportions s1/n1, s2/n2 (Campbell 2007; Richardson 2011), with
the 2x2 table a = s1, b = n1 - s1, c = s2, d = n2 - s2, N = n1 + n2:

    chi2 = (a d - b c)^2 (N - 1) / ((a + b)(c + d)(a + c)(b + d)),  p = P(chi2_1 > chi2)

(Pearson's statistic times (N - 1) / N; 0 with p = 1 when both groups all succeed or all fail;
with one degree of freedom P(chi2_1 > x) = erfc(sqrt(x / 2))).

Trial time (positively skewed): on y = log t, the geometric mean exp(mean y) and its CI
exp(mean y -/+ t_{0.975, n-1} sd(y) / sqrt(n)); two groups compare with a two-sample t-test on
log t (Welch's by default, Student's pooled with equal_var=True).

Trajectory distributions: the Jensen-Shannon divergence of two histograms P, Q (normalised to
sum 1), base 2, so it is bounded in [0, 1]:

    JSD(P, Q) = (KL(P || M) + KL(Q || M)) / 2,  M = (P + Q) / 2,  KL(P || M) = sum P log2(P / M)

(scipy.spatial.distance.jensenshannon returns its square root, the JS *distance*.)
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy import special

from dsteleop.errors import ContractError

Array = NDArray[np.float64]

Z95 = 1.959963984540054  # the 0.975 quantile of the standard normal
#: Norm [units of the actions] at or below which an action counts as idle (module docstring).
IDLE_TOL = 1e-9


@dataclass(frozen=True)
class CosineDistance:
    """Cosine distance of the actions of one or many sequences (batch shape (...)).

    Attributes:
        total: sum over the counted actions [unitless, each in [0, 2]]: the paper's metric.
        mean: total / n_actions, the mean per action (nan when no action was counted).
        n_actions: actions counted (both vectors non-zero).
        n_skipped: actions skipped as idle (`idle_actions`).
    """

    total: Array
    mean: Array
    n_actions: NDArray[np.int64]
    n_skipped: NDArray[np.int64]


@dataclass(frozen=True)
class Agreement:
    """Ratio of agreement of one or many sequences (batch shape (...)).

    Attributes:
        ratio: n_agree / n_actions in [0, 1] (nan when no action was counted).
        n_agree: actions with U_h . U_out > 0.
        n_actions: actions counted (neither vector idle, or all when skip_idle is False).
    """

    ratio: Array
    n_agree: NDArray[np.int64]
    n_actions: NDArray[np.int64]


@dataclass(frozen=True)
class SuccessRate:
    """Success rate of s successes in n trials: Laplace estimate and adjusted-Wald CI."""

    successes: int
    n: int
    laplace: float
    ci_low: float
    ci_high: float


@dataclass(frozen=True)
class ProportionTest:
    """N-1 chi-squared test of two proportions (1 degree of freedom)."""

    chi2: float
    p_value: float
    n: int


@dataclass(frozen=True)
class GeometricMean:
    """Geometric mean of positive samples (e.g. times [s]) and the 95 % CI of the log mean."""

    mean: float
    ci_low: float
    ci_high: float
    n: int


@dataclass(frozen=True)
class TTest:
    """Two-sample (or paired) t-test: statistic, two-sided p-value, degrees of freedom."""

    t: float
    p_value: float
    df: float


@dataclass(frozen=True)
class McNemarTest:
    """McNemar's test of paired success (module docstring).

    Attributes:
        first_only: pairs where only the first condition succeeded (b).
        second_only: pairs where only the second did (c).
        n: pairs.
        p_exact: two-sided exact binomial p-value.
        p_mid: two-sided mid-p value.
    """

    first_only: int
    second_only: int
    n: int
    p_exact: float
    p_mid: float


@dataclass(frozen=True)
class ActionProducts:
    """Per-action inner products of the operator's and the output's actions, the terms every
    action metric is made of: dot = U_h . U_out, hh = |U_h|^2, oo = |U_out|^2 (shape (...)).

    `of(U_h, U_out, weights)` computes them with per-dimension weights (the metric of a
    variant: all ones for the literal definitions, 1 / v_max^2 for actions divided by the
    velocity limits, zeros outside a group for one group alone).
    """

    dot: Array
    hh: Array
    oo: Array

    @classmethod
    def of(
        cls, U_h: ArrayLike, U_out: ArrayLike, weights: ArrayLike | None = None
    ) -> ActionProducts:
        a = np.asarray(U_h, dtype=np.float64)
        b = np.asarray(U_out, dtype=np.float64)
        w = np.ones(a.shape[-1]) if weights is None else np.asarray(weights, dtype=np.float64)
        return cls(
            np.einsum("...i,...i,i->...", a, b, w),
            np.einsum("...i,...i,i->...", a, a, w),
            np.einsum("...i,...i,i->...", b, b, w),
        )

    @classmethod
    def of_groups(
        cls, U_h: ArrayLike, U_out: ArrayLike, groups: Sequence[slice]
    ) -> list[ActionProducts]:
        """`of` on each group of dimensions alone (`of` with weights 1 in the group, 0
        elsewhere), reading only the group's dimensions."""
        a = np.asarray(U_h, dtype=np.float64)
        b = np.asarray(U_out, dtype=np.float64)
        return [cls.of(a[..., g], b[..., g]) for g in groups]

    @classmethod
    def combine(cls, parts: Sequence[ActionProducts], weights: Sequence[float]) -> ActionProducts:
        """sum_k weights[k] parts[k]: the products of disjoint groups of dimensions (`of_groups`)
        under one weight per group (the same as `of` with those per-dimension weights, to
        the rounding of the sums)."""

        def total(field: str) -> Array:
            out = weights[0] * getattr(parts[0], field)
            for p, w in zip(parts[1:], weights[1:], strict=True):
                out = out + w * getattr(p, field)
            return np.asarray(out)

        return cls(total("dot"), total("hh"), total("oo"))


def idle_actions(p: ActionProducts, tol: float = IDLE_TOL) -> NDArray[np.bool_]:
    """The actions that have no direction: |U_h| <= tol or |U_out| <= tol (shape (...)).
    Both the cosine distance and the ratio of agreement skip exactly these."""
    t2 = tol * tol
    return np.asarray((p.hh <= t2) | (p.oo <= t2))


def action_cosine_distance(U_h: ArrayLike, U_out: ArrayLike, tol: float = IDLE_TOL) -> Array:
    """Cosine distance of every action, (..., D) -> (...), nan where a vector is zero.

    Args:
        U_h: operator actions (..., D), e.g. [m/s, rad/s, 1/s].
        U_out: output actions (..., D), same units.
        tol: norms at or below this count as zero.
    """
    return cosine_distances(ActionProducts.of(U_h, U_out), tol)


def cosine_distances(p: ActionProducts, tol: float = IDLE_TOL) -> Array:
    """`action_cosine_distance` from the actions' products: 1 - dot / (|U_h| |U_out|), nan
    where the action is idle (`idle_actions`)."""
    ok = ~idle_actions(p, tol)
    cos = p.dot / np.where(ok, np.sqrt(p.hh) * np.sqrt(p.oo), 1.0)
    return np.where(ok, 1.0 - np.clip(cos, -1.0, 1.0), np.nan)


def cosine_distance(
    U_h: ArrayLike, U_out: ArrayLike, valid: ArrayLike | None = None, tol: float = IDLE_TOL
) -> CosineDistance:
    """Cosine distance summed and averaged over the actions of a sequence.

    Args:
        U_h: operator actions (..., T, D), T actions of D dimensions.
        U_out: output actions (..., T, D).
        valid: optional (..., T) mask of the actions that belong to the sequence (padding
            excluded); all by default.
        tol: norms at or below this count as zero (those actions are skipped).

    Returns:
        Sums, means and counts with the batch shape (...) (0-d arrays for one sequence).
    """
    return summarise_cosines(action_cosine_distance(U_h, U_out, tol), valid)


def summarise_cosines(c: ArrayLike, valid: ArrayLike | None = None) -> CosineDistance:
    """`cosine_distance` from the per-action distances c (..., T) (nan: skipped)."""
    c = np.asarray(c, dtype=np.float64)
    mask = np.ones(c.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    skipped = np.isnan(c)
    counted = mask & ~skipped
    total = np.where(counted, c, 0.0).sum(-1)
    n = counted.sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = np.where(n > 0, total / np.maximum(n, 1), np.nan)
    return CosineDistance(
        total=np.asarray(total, dtype=np.float64),
        mean=np.asarray(mean, dtype=np.float64),
        n_actions=np.asarray(n, dtype=np.int64),
        n_skipped=np.asarray((mask & skipped).sum(-1), dtype=np.int64),
    )


def agreement(
    U_h: ArrayLike,
    U_out: ArrayLike,
    valid: ArrayLike | None = None,
    skip_idle: bool = True,
    tol: float = IDLE_TOL,
) -> Agreement:
    """Ratio of agreement: the share of actions with U_h . U_out > 0.

    Args:
        U_h: operator actions (..., T, D).
        U_out: output actions (..., T, D).
        valid: optional (..., T) mask of the actions that belong to the sequence.
        skip_idle: leave out the idle actions (`idle_actions`: the operator or the output
            is still), exactly those the cosine distance skips; False: the paper's literal
            count over every action.
        tol: norm at or below which a vector counts as idle.

    Returns:
        Ratio and counts with the batch shape (...).
    """
    return agreement_of(ActionProducts.of(U_h, U_out), valid, skip_idle, tol)


def agreement_of(
    p: ActionProducts,
    valid: ArrayLike | None = None,
    skip_idle: bool = True,
    tol: float = IDLE_TOL,
) -> Agreement:
    """`agreement` from the actions' products (..., T)."""
    mask = np.ones(p.dot.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if skip_idle:
        mask = mask & ~idle_actions(p, tol)
    n = mask.sum(-1)
    k = (mask & (p.dot > 0.0)).sum(-1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = np.where(n > 0, k / np.maximum(n, 1), np.nan)
    return Agreement(
        ratio=np.asarray(ratio, dtype=np.float64),
        n_agree=np.asarray(k, dtype=np.int64),
        n_actions=np.asarray(n, dtype=np.int64),
    )


def success_rate(successes: int, n: int, z: float = Z95) -> SuccessRate:
    """Laplace estimate (s + 1) / (n + 2) with the adjusted-Wald CI (see module docstring).

    Args:
        successes: s, 0 <= s <= n.
        n: number of trials, >= 0.
        z: normal quantile of the interval (1.96 for 95 %).
    """
    s, n = _check_counts(successes, n)
    z2 = z * z
    p_adj = (s + z2 / 2.0) / (n + z2)
    half = z * math.sqrt(p_adj * (1.0 - p_adj) / (n + z2))
    return SuccessRate(
        successes=s,
        n=n,
        laplace=(s + 1.0) / (n + 2.0),
        ci_low=max(0.0, p_adj - half),
        ci_high=min(1.0, p_adj + half),
    )


def n1_chi_squared(s1: int, n1: int, s2: int, n2: int) -> ProportionTest:
    """N-1 chi-squared test between the proportions s1/n1 and s2/n2 (two-sided).

    Raises:
        ContractError: a count is negative, s > n, or a group is empty.
    """
    a, n1 = _check_counts(s1, n1)
    c, n2 = _check_counts(s2, n2)
    if n1 == 0 or n2 == 0:
        raise ContractError("both groups need at least one trial")
    b, d = n1 - a, n2 - c
    N = n1 + n2
    den = float(n1) * n2 * (a + c) * (b + d)
    if den == 0.0:
        return ProportionTest(chi2=0.0, p_value=1.0, n=N)
    chi2 = float(a * d - b * c) ** 2 * (N - 1) / den
    return ProportionTest(chi2=chi2, p_value=float(special.erfc(math.sqrt(chi2 / 2.0))), n=N)


def mcnemar(first: ArrayLike, second: ArrayLike) -> McNemarTest:
    """McNemar's exact and mid-p test of paired success (module docstring).

    Args:
        first: (n,) success (bool or 0/1) of each trial under the first condition.
        second: (n,) success of the same trials under the second condition.

    Raises:
        ContractError: different shapes, or a value that is not 0/1.
    """
    a, b = np.asarray(first), np.asarray(second)
    if a.shape != b.shape:
        raise ContractError(f"paired outcomes differ in shape: {a.shape} vs {b.shape}")
    for x in (a, b):
        if not np.isin(x, (0, 1)).all():
            raise ContractError("paired outcomes must be booleans or 0/1")
    a, b = a.astype(bool).ravel(), b.astype(bool).ravel()
    n_b, n_c = int(np.sum(a & ~b)), int(np.sum(~a & b))
    n = n_b + n_c
    if n == 0:
        return McNemarTest(n_b, n_c, int(a.size), 1.0, 1.0)
    k = min(n_b, n_c)
    cdf = float(special.bdtr(k, n, 0.5))
    pmf = cdf - (float(special.bdtr(k - 1, n, 0.5)) if k > 0 else 0.0)
    return McNemarTest(
        n_b, n_c, int(a.size), min(1.0, 2.0 * cdf), min(1.0, max(0.0, 2.0 * cdf - pmf))
    )


def geometric_mean(samples: ArrayLike, confidence: float = 0.95) -> GeometricMean:
    """Geometric mean of positive samples and the t-interval of their log mean.

    Args:
        samples: (n,) positive values, e.g. trial times [s]; n >= 2 for an interval (with
            n = 1 the interval is the point itself).
        confidence: level of the interval.

    Raises:
        ContractError: empty input, or a sample that is not finite and > 0.
    """
    y = _logs(samples)
    n = y.size
    m = float(y.mean())
    if n < 2:
        return GeometricMean(math.exp(m), math.exp(m), math.exp(m), n)
    se = float(y.std(ddof=1)) / math.sqrt(n)
    half = t_quantile(0.5 + confidence / 2.0, n - 1) * se
    return GeometricMean(math.exp(m), math.exp(m - half), math.exp(m + half), n)


def log_t_test(a: ArrayLike, b: ArrayLike, equal_var: bool = False) -> TTest:
    """Two-sample t-test on the logs of positive samples (e.g. trial times)."""
    return t_test(_logs(a), _logs(b), equal_var=equal_var)


def t_test(a: ArrayLike, b: ArrayLike, equal_var: bool = False) -> TTest:
    """Two-sample t-test, two-sided: Welch's by default, Student's pooled with equal_var.

    Raises:
        ContractError: fewer than two samples in a group, or a non-finite sample.
    """
    x, y = _finite(a), _finite(b)
    if x.size < 2 or y.size < 2:
        raise ContractError("a t-test needs at least two samples per group")
    n1, n2 = x.size, y.size
    v1, v2 = float(x.var(ddof=1)), float(y.var(ddof=1))
    diff = float(x.mean() - y.mean())
    if equal_var:
        df = float(n1 + n2 - 2)
        sp2 = ((n1 - 1) * v1 + (n2 - 1) * v2) / df
        se = math.sqrt(sp2 * (1.0 / n1 + 1.0 / n2))
    else:
        g1, g2 = v1 / n1, v2 / n2
        se = math.sqrt(g1 + g2)
        den = g1 * g1 / (n1 - 1) + g2 * g2 / (n2 - 1)
        df = (g1 + g2) ** 2 / den if den > 0 else float(n1 + n2 - 2)
    return _t_result(diff, se, df)


def paired_t_test(a: ArrayLike, b: ArrayLike) -> TTest:
    """Paired t-test of a - b (same trials under two conditions), two-sided.

    Raises:
        ContractError: different lengths, fewer than two pairs, or a non-finite sample.
    """
    x, y = _finite(a), _finite(b)
    if x.shape != y.shape or x.size < 2:
        raise ContractError("a paired t-test needs two equally long samples of at least two")
    d = x - y
    se = float(d.std(ddof=1)) / math.sqrt(d.size)
    return _t_result(float(d.mean()), se, float(d.size - 1))


@dataclass(frozen=True)
class Difference:
    """Mean paired difference a - b with its t interval (`paired_difference`)."""

    mean: float
    ci_low: float
    ci_high: float
    n: int


def paired_difference(a: ArrayLike, b: ArrayLike, confidence: float = 0.95) -> Difference:
    """Mean of a - b over pairs (the same trials under two conditions) and its t interval,
    mean -/+ t_{(1 + confidence) / 2, n - 1} sd(a - b) / sqrt(n); pairs where either value is
    not finite are dropped. For 0/1 outcomes (success) it is the Wald interval of a paired
    difference of proportions with a t quantile.

    Raises:
        ContractError: different shapes, or fewer than two finite pairs.
    """
    x, y = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if x.shape != y.shape:
        raise ContractError("a paired difference needs two equally long samples")
    ok = np.isfinite(x) & np.isfinite(y)
    d = x[ok] - y[ok]
    if d.size < 2:
        raise ContractError("a paired difference needs at least two finite pairs")
    m = float(d.mean())
    half = t_quantile(0.5 + confidence / 2.0, d.size - 1) * float(d.std(ddof=1)) / math.sqrt(d.size)
    return Difference(m, m - half, m + half, int(d.size))


def js_divergence(P: ArrayLike, Q: ArrayLike) -> float:
    """Jensen-Shannon divergence (base 2, in [0, 1]) of two histograms of the same shape.

    Args:
        P, Q: non-negative counts or densities of any (equal) shape; each is normalised to
            sum 1.

    Raises:
        ContractError: shapes differ, a value is negative or not finite, or a histogram is empty.
    """
    p = np.asarray(P, dtype=np.float64)
    q = np.asarray(Q, dtype=np.float64)
    if p.shape != q.shape:
        raise ContractError(f"histograms differ in shape: {p.shape} vs {q.shape}")
    for h in (p, q):
        if not np.isfinite(h).all() or (h < 0).any() or h.sum() <= 0:
            raise ContractError("histograms must be finite, non-negative and not empty")
    p = p.ravel() / p.sum()
    q = q.ravel() / q.sum()
    m = 0.5 * (p + q)
    js = 0.5 * (_kl2(p, m) + _kl2(q, m))
    return float(min(1.0, max(0.0, js)))


def trajectory_histogram(
    points: ArrayLike, bins: int | tuple[int, ...], ranges: ArrayLike
) -> NDArray[np.int64]:
    """Counts of trajectory points in a regular grid (e.g. 3-D: x, y, heading).

    Args:
        points: (M, K) points (any leading shape is flattened to M); nan rows are dropped.
        bins: bins per axis.
        ranges: (K, 2) lower and upper edge per axis; points outside are dropped.
    """
    pts = np.asarray(points, dtype=np.float64)
    pts = pts.reshape(-1, pts.shape[-1])
    finite = np.isfinite(pts).all(-1)
    if not finite.all():
        pts = pts[finite]
    rng = np.asarray(ranges, dtype=np.float64)
    counts, _ = np.histogramdd(pts, bins=bins, range=[tuple(r) for r in rng])
    return np.asarray(counts, dtype=np.int64)


def t_quantile(q: float, df: float) -> float:
    """Quantile q of Student's t with df degrees of freedom (scipy.special, no scipy.stats)."""
    return float(special.stdtrit(df, q))


def _kl2(p: Array, m: Array) -> float:
    nz = p > 0
    return float(np.sum(p[nz] * np.log2(p[nz] / m[nz])))


def _t_result(diff: float, se: float, df: float) -> TTest:
    if se == 0.0:
        # No spread: equal means are no evidence of a difference; different ones are certain.
        return TTest(0.0, 1.0, df) if diff == 0.0 else TTest(math.copysign(math.inf, diff), 0.0, df)
    t = diff / se
    return TTest(t, float(2.0 * special.stdtr(df, -abs(t))), df)


def _check_counts(s: int, n: int) -> tuple[int, int]:
    s_i, n_i = int(s), int(n)
    if s_i != s or n_i != n or n_i < 0 or not 0 <= s_i <= n_i:
        raise ContractError(f"need integers 0 <= successes <= n, got {s!r} of {n!r}")
    return s_i, n_i


def _finite(a: ArrayLike) -> Array:
    x = np.asarray(a, dtype=np.float64).ravel()
    if not np.isfinite(x).all():
        raise ContractError("samples must be finite")
    return x


def _logs(samples: ArrayLike) -> Array:
    x = _finite(samples)
    if x.size == 0 or (x <= 0).any():
        raise ContractError("need at least one sample, all > 0")
    return np.log(x)
