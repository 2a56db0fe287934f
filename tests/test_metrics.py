"""Metrics of Section IV-D against hand-worked and published numbers, plus properties."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp
from numpy.typing import NDArray
from scipy import stats
from scipy.spatial.distance import jensenshannon

from dsteleop.arbitration import metrics

finite = st.floats(-10.0, 10.0, allow_nan=False, allow_infinity=False)
vectors = hnp.arrays(np.float64, st.tuples(st.integers(1, 12), st.just(4)), elements=finite)


# --- cosine distance and ratio of agreement -------------------------------------------------


def test_cosine_distance_hand_worked() -> None:
    # Action 1: [1,0] vs [1,1]: 1 - 1/sqrt(2) = 0.2928932
    # Action 2: [1,0] vs [-1,0]: 1 - (-1) = 2
    # Action 3: [0,0] vs [1,0]: zero-norm operator action -> skipped
    # Action 4: [0,3] vs [0,0]: zero-norm output -> skipped
    U_h = [[1, 0], [1, 0], [0, 0], [0, 3]]
    U_out = [[1, 1], [-1, 0], [1, 0], [0, 0]]
    r = metrics.cosine_distance(U_h, U_out)
    assert float(r.total) == pytest.approx(2.0 + 1.0 - 1.0 / math.sqrt(2.0))
    assert float(r.mean) == pytest.approx((2.0 + 1.0 - 1.0 / math.sqrt(2.0)) / 2.0)
    assert int(r.n_actions) == 2
    assert int(r.n_skipped) == 2


def test_agreement_hand_worked() -> None:
    # dots: 1 (agree), -1 (disagree), idle operator (skipped), idle output (skipped: the
    # same actions the cosine distance skips) -> 1 of 2.
    U_h = [[1, 0], [1, 0], [0, 0], [0, 3]]
    U_out = [[1, 1], [-1, 0], [1, 0], [0, 0]]
    r = metrics.agreement(U_h, U_out)
    assert int(r.n_agree) == 1
    assert int(r.n_actions) == 2
    assert float(r.ratio) == pytest.approx(1.0 / 2.0)
    # The paper's literal count over every action: 1 of 4.
    assert float(metrics.agreement(U_h, U_out, skip_idle=False).ratio) == pytest.approx(0.25)


def test_idle_actions_are_skipped_alike_by_both_metrics() -> None:
    # An output under IDLE_TOL (numerically zero), an operator under it, and moving ones.
    tiny = 0.5 * metrics.IDLE_TOL
    U_h = np.array([[1.0, 0.0], [tiny, 0.0], [0.0, 1.0], [1.0, 1.0], [0.0, 0.0]])
    U_out = np.array([[tiny, 0.0], [1.0, 0.0], [0.0, -2.0], [1.0, 0.0], [0.0, 0.0]])
    idle = metrics.idle_actions(metrics.ActionProducts.of(U_h, U_out))
    assert idle.tolist() == [True, True, False, False, True]
    c = metrics.cosine_distance(U_h, U_out)
    a = metrics.agreement(U_h, U_out)
    assert int(c.n_actions) == int(a.n_actions) == 2
    assert int(c.n_skipped) == 3
    assert int(a.n_agree) == 1
    assert float(c.total) == pytest.approx(2.0 + 1.0 - 1.0 / math.sqrt(2.0))


@given(
    hnp.arrays(np.float64, st.tuples(st.integers(1, 8), st.just(6)), elements=finite),
    hnp.arrays(np.float64, st.tuples(st.integers(1, 8), st.just(6)), elements=finite),
    st.floats(0.1, 10.0),
    st.floats(0.1, 10.0),
)
@settings(max_examples=50, deadline=None)
def test_group_products_combine_to_the_weighted_ones(
    a: NDArray[np.float64], b: NDArray[np.float64], w_t: float, w_r: float
) -> None:
    """Products of the translation and rotation groups, combined with one weight each, are
    `of` with those weights per dimension (to the rounding of the sums)."""
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    parts = metrics.ActionProducts.of_groups(a, b, (slice(0, 3), slice(3, 6)))
    whole = metrics.ActionProducts.of(a, b, [w_t] * 3 + [w_r] * 3)
    got = metrics.ActionProducts.combine(parts, (w_t, w_r))
    for name in ("dot", "hh", "oo"):
        np.testing.assert_allclose(getattr(got, name), getattr(whole, name), rtol=1e-12, atol=1e-9)
    plain = metrics.ActionProducts.combine(parts, (1.0, 1.0))
    np.testing.assert_allclose(plain.dot, metrics.ActionProducts.of(a, b).dot, atol=1e-9)


def test_metrics_batch_and_mask() -> None:
    U_h = np.array([[[1.0, 0.0], [1.0, 0.0]], [[0.0, 1.0], [0.0, 1.0]]])
    U_out = np.array([[[1.0, 0.0], [-1.0, 0.0]], [[0.0, 2.0], [5.0, 0.0]]])
    valid = np.array([[True, True], [True, False]])
    c = metrics.cosine_distance(U_h, U_out, valid)
    np.testing.assert_allclose(c.total, [2.0, 0.0])
    np.testing.assert_array_equal(c.n_actions, [2, 1])
    a = metrics.agreement(U_h, U_out, valid)
    np.testing.assert_allclose(a.ratio, [0.5, 1.0])


def test_no_action_gives_nan() -> None:
    r = metrics.cosine_distance(np.zeros((3, 2)), np.ones((3, 2)))
    assert int(r.n_actions) == 0 and math.isnan(float(r.mean))
    assert math.isnan(float(metrics.agreement(np.zeros((3, 2)), np.ones((3, 2))).ratio))


@given(vectors, vectors)
def test_cosine_and_agreement_bounds(a: NDArray[np.float64], b: NDArray[np.float64]) -> None:
    n = min(len(a), len(b))
    a, b = a[:n], b[:n]
    c = metrics.action_cosine_distance(a, b)
    ok = ~np.isnan(c)
    assert ((c[ok] >= 0.0) & (c[ok] <= 2.0)).all()
    r = metrics.agreement(a, b).ratio
    assert np.isnan(r) or 0.0 <= float(r) <= 1.0


@given(vectors, st.floats(0.01, 100.0))
def test_identical_actions_agree_fully_and_scale_does_not_matter(
    a: NDArray[np.float64], k: float
) -> None:
    moving = np.linalg.norm(a, axis=-1) > 1e-6
    c = metrics.cosine_distance(a[moving], k * a[moving])
    assert float(c.total) == pytest.approx(0.0, abs=1e-9)
    if moving.any():
        assert float(metrics.agreement(a[moving], k * a[moving]).ratio) == 1.0


# --- success rate ---------------------------------------------------------------------------


def test_success_rate_matches_paper_table_1() -> None:
    # Table I: DS 0.446 [0.346, 0.547], S 0.326 [0.234, 0.425], 90 runs each.
    # Laplace (s + 1) / 92 = 0.446 -> s = 40; = 0.326 -> s = 29.
    # By hand, DS, z^2 = 3.8415: p_a = (40 + 1.9208) / 93.8415 = 0.44672,
    #   half = 1.96 * sqrt(0.44672 * 0.55328 / 93.8415) = 1.96 * 0.051321 = 0.10059
    #   -> [0.3461, 0.5473].
    ds = metrics.success_rate(40, 90)
    assert ds.laplace == pytest.approx(0.446, abs=5e-4)
    assert (ds.ci_low, ds.ci_high) == pytest.approx((0.346, 0.547), abs=5e-4)
    s = metrics.success_rate(29, 90)
    assert s.laplace == pytest.approx(0.326, abs=5e-4)
    assert (s.ci_low, s.ci_high) == pytest.approx((0.234, 0.425), abs=5e-4)


def test_adjusted_wald_hand_worked() -> None:
    # 7 of 10: p_a = 8.9208 / 13.8415 = 0.64450; se = sqrt(0.6445 * 0.3555 / 13.8415)
    # = 0.12866; half = 0.25217 -> [0.3923, 0.8967]; Laplace 8 / 12 = 0.6667.
    r = metrics.success_rate(7, 10)
    assert r.laplace == pytest.approx(8.0 / 12.0)
    assert (r.ci_low, r.ci_high) == pytest.approx((0.3923, 0.8967), abs=1e-4)
    # 10 of 10: the upper bound is clipped at 1.
    assert metrics.success_rate(10, 10).ci_high == 1.0


@given(st.integers(0, 500), st.integers(0, 500))
def test_success_interval_properties(s: int, extra: int) -> None:
    n = s + extra
    r = metrics.success_rate(s, n)
    assert 0.0 <= r.ci_low <= r.ci_high <= 1.0
    assert r.ci_low <= r.laplace <= r.ci_high


@pytest.mark.parametrize("bad", [(-1, 5), (6, 5), (1.5, 5), (0, -1)])
def test_success_rate_rejects_bad_counts(bad: tuple[float, int]) -> None:
    with pytest.raises(ValueError):
        metrics.success_rate(*bad)  # type: ignore[arg-type]  # 1.5 is a deliberately bad count


# --- N-1 chi-squared ------------------------------------------------------------------------


def test_n1_chi_squared_matches_paper() -> None:
    # Table I's success rates: 40/90 (DS) vs 29/90 (S); the paper reports p = 0.092.
    # By hand: a=40, b=50, c=29, d=61, N=180; ad - bc = 2440 - 1450 = 990;
    # chi2 = 990^2 * 179 / (90 * 90 * 69 * 111) = 175437900 / 62037900 = 2.82791;
    # p = P(chi2_1 > 2.82791) = 0.0926.
    r = metrics.n1_chi_squared(40, 90, 29, 90)
    assert r.chi2 == pytest.approx(2.82791, abs=1e-5)
    assert r.p_value == pytest.approx(0.0926, abs=1e-4)
    assert round(r.p_value, 3) == pytest.approx(0.093, abs=1e-3)  # paper: 0.092 (truncated)


@given(st.integers(1, 200), st.integers(1, 200), st.data())
def test_n1_chi_squared_is_pearson_times_n_minus_1_over_n(
    n1: int, n2: int, data: st.DataObject
) -> None:
    s1 = data.draw(st.integers(0, n1))
    s2 = data.draw(st.integers(0, n2))
    r = metrics.n1_chi_squared(s1, n1, s2, n2)
    assert 0.0 <= r.p_value <= 1.0
    assert metrics.n1_chi_squared(s2, n2, s1, n1).chi2 == pytest.approx(r.chi2)
    table = np.array([[s1, n1 - s1], [s2, n2 - s2]])
    if (table.sum(0) > 0).all():
        pearson = stats.chi2_contingency(table, correction=False)[0]
        N = n1 + n2
        assert r.chi2 == pytest.approx(pearson * (N - 1) / N, rel=1e-9, abs=1e-12)
    else:
        assert (r.chi2, r.p_value) == (0.0, 1.0)


# --- time: geometric mean and t-tests -------------------------------------------------------


def test_geometric_mean_hand_worked() -> None:
    # logs of 10, 20, 40: 2.302585, 2.995732, 3.688879; mean 2.995732 -> exp = 20;
    # sd = 0.693147 (= ln 2), se = 0.400189, t_{0.975, 2} = 4.302653, half = 1.721869;
    # CI = exp(2.995732 -/+ 1.721869) = [3.5746, 111.900].
    r = metrics.geometric_mean([10.0, 20.0, 40.0])
    assert r.mean == pytest.approx(20.0)
    assert (r.ci_low, r.ci_high) == pytest.approx((3.5746, 111.900), rel=1e-4)
    assert r.n == 3


def test_log_t_test_hand_worked() -> None:
    # logs 1, 2, 3 vs 2, 3, 4: means 2 and 3, sd 1 each, n = 3; pooled se = sqrt(2/3)
    # = 0.816497, t = -1 / 0.816497 = -1.224745, df = 4 (Welch gives the same here);
    # two-sided p from the t table (df 4): 0.2879.
    for equal_var in (True, False):
        r = metrics.log_t_test(np.exp([1.0, 2.0, 3.0]), np.exp([2.0, 3.0, 4.0]), equal_var)
        assert r.t == pytest.approx(-1.224745, abs=1e-6)
        assert r.df == pytest.approx(4.0)
        assert r.p_value == pytest.approx(0.2879, abs=1e-4)


@given(
    hnp.arrays(np.float64, st.integers(2, 30), elements=st.floats(-50, 50)),
    hnp.arrays(np.float64, st.integers(2, 30), elements=st.floats(-50, 50)),
    st.booleans(),
)
@settings(max_examples=50)
def test_t_test_matches_scipy(
    a: NDArray[np.float64], b: NDArray[np.float64], equal_var: bool
) -> None:
    r = metrics.t_test(a, b, equal_var=equal_var)
    assert 0.0 <= r.p_value <= 1.0
    if a.std() > 1e-6 and b.std() > 1e-6:
        ref = stats.ttest_ind(a, b, equal_var=equal_var)
        assert r.t == pytest.approx(ref.statistic, rel=1e-6)
        assert r.p_value == pytest.approx(ref.pvalue, rel=1e-6, abs=1e-12)


def test_paired_t_test_hand_worked() -> None:
    # differences 1, 2, 3: mean 2, sd 1, se 1/sqrt(3), t = 2 sqrt(3) = 3.464102, df 2,
    # two-sided p = 0.0742 (t table, df 2).
    r = metrics.paired_t_test([2.0, 4.0, 6.0], [1.0, 2.0, 3.0])
    assert r.t == pytest.approx(3.464102, abs=1e-6)
    assert r.df == 2.0
    assert r.p_value == pytest.approx(0.0742, abs=1e-4)


def test_time_metrics_reject_bad_samples() -> None:
    with pytest.raises(ValueError):
        metrics.geometric_mean([1.0, 0.0])
    with pytest.raises(ValueError):
        metrics.geometric_mean([])
    with pytest.raises(ValueError):
        metrics.t_test([1.0], [1.0, 2.0])


# --- Jensen-Shannon divergence --------------------------------------------------------------


def test_js_divergence_hand_worked() -> None:
    # Disjoint supports: JSD = 1 (the bound).
    assert metrics.js_divergence([1, 0], [0, 1]) == pytest.approx(1.0)
    # P = [.5, .5], Q = [1, 0], M = [.75, .25]:
    # KL(P||M) = .5 log2(.5/.75) + .5 log2(.5/.25) = .5 (-0.584963) + .5 = 0.207519
    # KL(Q||M) = log2(1/.75) = 0.415037;  JSD = (0.207519 + 0.415037) / 2 = 0.311278
    assert metrics.js_divergence([0.5, 0.5], [1, 0]) == pytest.approx(0.311278, abs=1e-6)
    # Counts are normalised: [2, 2] is the same distribution as [.5, .5].
    assert metrics.js_divergence([2, 2], [3, 0]) == pytest.approx(0.311278, abs=1e-6)


@given(
    hnp.arrays(np.float64, (3, 2, 2), elements=st.floats(0, 10)),
    hnp.arrays(np.float64, (3, 2, 2), elements=st.floats(0, 10)),
)
def test_js_divergence_properties(p: NDArray[np.float64], q: NDArray[np.float64]) -> None:
    if p.sum() <= 1e-6 or q.sum() <= 1e-6:
        return
    d = metrics.js_divergence(p, q)
    assert 0.0 <= d <= 1.0
    assert metrics.js_divergence(q, p) == pytest.approx(d, abs=1e-12)
    assert metrics.js_divergence(p, p) == pytest.approx(0.0, abs=1e-12)
    ref = jensenshannon(p.ravel(), q.ravel(), base=2) ** 2
    assert d == pytest.approx(ref, abs=1e-9)


def test_trajectory_histogram_counts_points_in_range() -> None:
    pts = np.array([[0.1, 0.1, 0.1], [0.9, 0.9, 0.9], [0.9, 0.9, 0.9], [2.0, 0, 0], [np.nan, 0, 0]])
    h = metrics.trajectory_histogram(pts, 2, [[0, 1], [0, 1], [0, 1]])
    assert h.shape == (2, 2, 2)
    assert h[0, 0, 0] == 1 and h[1, 1, 1] == 2 and h.sum() == 3


def test_js_divergence_rejects_bad_histograms() -> None:
    with pytest.raises(ValueError):
        metrics.js_divergence([1, 2], [1, 2, 3])
    with pytest.raises(ValueError):
        metrics.js_divergence([0, 0], [1, 0])
    with pytest.raises(ValueError):
        metrics.js_divergence([-1, 2], [1, 0])


# --- McNemar's test of paired success ---------------------------------------------------------


def test_mcnemar_hand_worked() -> None:
    # 10 pairs: 1 only the first succeeded, 6 only the second, 3 concordant. Under H0,
    # X ~ Bin(7, 1/2): P(X <= 1) = (1 + 7) / 128, P(X = 1) = 7 / 128.
    first = [1, 0, 0, 0, 0, 0, 0, 1, 1, 0]
    second = [0, 1, 1, 1, 1, 1, 1, 1, 1, 0]
    r = metrics.mcnemar(first, second)
    assert (r.first_only, r.second_only, r.n) == (1, 6, 10)
    assert r.p_exact == pytest.approx(2 * 8 / 128, rel=1e-12)
    assert r.p_mid == pytest.approx(2 * 8 / 128 - 7 / 128, rel=1e-12)


def test_mcnemar_no_discordant_pairs_and_symmetry() -> None:
    same = metrics.mcnemar([True, False, True], [True, False, True])
    assert (same.p_exact, same.p_mid) == (1.0, 1.0)
    a = metrics.mcnemar([1, 1, 0, 0], [0, 0, 1, 1])
    assert a.p_exact == 1.0 and a.p_mid == pytest.approx(1.0)
    with pytest.raises(ValueError, match="shape"):
        metrics.mcnemar([1, 0], [1])
    with pytest.raises(ValueError, match="0/1"):
        metrics.mcnemar([2, 0], [1, 0])


@given(st.integers(0, 60), st.integers(0, 60), st.integers(0, 30))
def test_mcnemar_matches_scipy_binomtest(b: int, c: int, same: int) -> None:
    first = np.r_[np.ones(b), np.zeros(c), np.ones(same)]
    second = np.r_[np.zeros(b), np.ones(c), np.ones(same)]
    r = metrics.mcnemar(first, second)
    if b + c == 0:
        assert r.p_exact == 1.0
        return
    ref = stats.binomtest(min(b, c), b + c, 0.5).pvalue
    assert r.p_exact == pytest.approx(ref, rel=1e-9, abs=1e-15)
    k, n = min(b, c), b + c
    mid = min(1.0, 2 * stats.binom.cdf(k, n, 0.5) - stats.binom.pmf(k, n, 0.5))
    assert r.p_mid == pytest.approx(mid, rel=1e-9, abs=1e-15)
