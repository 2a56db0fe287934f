"""Batched path of one tick: many trajectories at once, laid out component-major for numpy.

Same quantities and formulas as the rest of the package (the maths is stated once, in
`se3.py`, `allocation.py` and `arbiters.py`, eq 1-8); only the memory layout and the order of
work differ, for throughput on a batch of N trajectories (1000 at ~1 us each is the target):

* Arrays are (component, ..., N): every numpy call works on contiguous rows of N values, a
  group norm is a sum of three rows, and outputs are transposed views, batch first.
* The six relative rotations of a tick are laid out as a grid of pairs, left (goal, hum, cur)
  x right ((hum, cur), (hum_prev, hum_start), (prev, start)). Only what the SO(3) logarithm
  needs is computed: the trace of M = R_a R_b^T and its skew part (m21 - m12, m02 - m20,
  m10 - m01), 27 products per pair as passes over 6N values, instead of a stacked 3x3 matmul.
* theta / sin(theta) takes sin(theta) = sqrt((1 - c)(1 + c)) from the same clipped cosine c
  as theta = arccos(c): both follow c, so the ratio keeps its digits. Pairs in the
  small-angle branch of `se3.so3_log` get its series; the few near pi are recomputed by the
  near-pi formula on their own matrices.
* erfc (translation, fingers) and cos (rotation) run only on the entries that need them;
  scratch arrays come from one allocation per tick, so the heap stays warm between ticks.

`tests/test_arbitration_perf_equivalence.py` checks this path, and the scalar one, against a
plain numpy reference of the formulas to 1e-9.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.special import erfc

from dsteleop.arbitration.scalar import log_rel
from dsteleop.arbitration.se3 import HandState, so3_log

Array = NDArray[np.float64]
#: A window row, as `arbiters.FilterState` keeps it: (..., D), or a tuple of D floats.
Row = Array | tuple[float, ...]

_SMALL = 1e-4
_NEAR_PI = np.pi - 1e-3


@dataclass(frozen=True)
class Tick:
    """Mode-independent quantities of one batched tick, component-major.

    Attributes:
        U, P, psi: (D, 2, N) velocities, allocations and expected speed changes, agent axis
            [human, robot].
        B_raw: (D, N) unfiltered willingness.
        batch: the batch shape (...) of the inputs; N = prod(batch).
        R_cur: (3, 3, N) rotation of the current state, R_cur[i, k, n] = R[n, i, k].
        p_cur: (3, N) position, g_cur: (F, N) openness of the current state.
    """

    U: Array
    P: Array
    psi: Array
    B_raw: Array
    batch: tuple[int, ...]
    R_cur: Array
    p_cur: Array
    g_cur: Array


def _batch_shape(states: tuple[HandState, ...]) -> tuple[int, ...]:
    shapes = set()
    for s in states:
        shapes.add(s.position.shape[:-1])
        shapes.add(s.rotation.shape[:-2])
        shapes.add(s.openness.shape[:-1])
    if len(shapes) == 1:
        return shapes.pop()
    return tuple(np.broadcast_shapes(*shapes))


def _rows(x: Array, batch: tuple[int, ...], tail: tuple[int, ...], N: int) -> Array:
    """x broadcast to batch + tail, as (N, *tail) (a view when x has that batch already)."""
    if x.shape[: x.ndim - len(tail)] != batch:
        x = np.broadcast_to(x, batch + tail)
    return np.asarray(x, dtype=np.float64).reshape((N, *tail))


def kernel(
    inp_states: tuple[HandState, ...],
    dt: float,
    history: Array | None,
    gains: Array,
    v_max: Array,
    eps: Array,
    kappa: float,
    p: float,
    q: float,
    b: float,
    floor: float,
) -> Tick:
    """U, P, psi and B of one tick for a batch (see `arbiters.py` for the equations).

    Args:
        inp_states: (human, human_prev, human_start, current, prev, start, goal).
        dt: tick length [s].
        history: (6 + F,) history term of eq (6), or None.
        gains, v_max, eps: (6 + F,) per-dimension vectors of the config.
        kappa, p, q, b, floor: hyper-parameters of eq (5) and (7).
    """
    batch = _batch_shape(inp_states)
    N = math.prod(batch)
    F = inp_states[3].openness.shape[-1]
    D = 6 + F
    H, Hp, Hs, C, Cp, Cs, G = (
        (
            _rows(s.position, batch, (3,), N),
            _rows(s.rotation, batch, (3, 3), N),
            _rows(s.openness, batch, (F,), N),
        )
        for s in inp_states
    )
    # Pair grid (left, right): left (goal, hum, cur) x right [[hum, cur], [hum_prev, hum_start],
    # [prev, start]], so pair index 2 * l + r is 0 goal-hum, 1 goal-cur, 2 hum-hum_prev,
    # 3 hum-hum_start, 4 cur-prev, 5 cur-start.
    lefts = (G, H, C)
    rights = ((H, C), (Hp, Hs), (Cp, Cs))
    # Rotations component-major, A[i, k, l, r, n] = R_left[n, i, k] (the left factor of each
    # pair materialised, so every product is one pass over 6N values), likewise Bm for the right.
    # One block for the three big scratch arrays of the tick (A, Bm, the differences d): one
    # allocation instead of three keeps the allocator's heap warm between ticks (no page
    # faults on fresh memory, ~1 us each, a few hundred per tick otherwise).
    work = np.empty((2 * 54 + 6 * D) * N)
    A = work[: 54 * N].reshape(3, 3, 3, 2, N)
    Bm = work[54 * N : 108 * N].reshape(3, 3, 3, 2, N)
    d = work[108 * N :].reshape(D, 3, 2, N)
    # Translation and finger differences: right states copied in component-major, then one
    # broadcast subtraction from the left states (as rows: small strided ops are slow).
    left = np.empty((D - 3, 3, 1, N))
    for l_, L in enumerate(lefts):
        A[:, :, l_, 0] = L[1].transpose(1, 2, 0)
        A[:, :, l_, 1] = A[:, :, l_, 0]
        left[0:3, l_, 0] = L[0].T
        left[3:, l_, 0] = L[2].T
        for r_, Rt in enumerate(rights[l_]):
            Bm[:, :, l_, r_] = Rt[1].transpose(1, 2, 0)
            d[0:3, l_, r_] = Rt[0].T
            d[6:, l_, r_] = Rt[2].T
    np.subtract(left[0:3], d[0:3], out=d[0:3])
    np.subtract(left[3:], d[6:], out=d[6:])
    _log_pairs(A, Bm, d[3:6])

    # eq (4)/(5): [P(H), P(R)] from [goal - hum, goal - cur]; denominators |goal - start|.
    P = np.empty((D, 2, N))
    den_t = np.maximum(np.abs(G[0] - Cs[0]), eps[0:3]).T[:, None]
    np.abs(d[0:3, 0], out=P[0:3])
    np.divide(P[0:3], den_t, out=P[0:3])
    erfc(P[0:3], out=P[0:3])
    if F:
        den_f = np.maximum(np.abs(G[2] - Cs[2]), eps[6:]).T[:, None]
        np.abs(d[6:, 0], out=P[6:])
        np.divide(P[6:], den_f, out=P[6:])
        erfc(P[6:], out=P[6:])
    Pr = P[3:6]
    np.cos(d[3:6, 0], out=Pr)
    Pr -= 1.0
    Pr *= kappa
    np.exp(Pr, out=Pr)

    # [U_human, U_robot] = sat([(hum - hum_prev) / dt, K_r (goal - cur)]).
    d6 = d.reshape(D, 6, N)
    scale = np.empty((D, 2, 1))
    scale[:, 0, 0] = 1.0 / dt
    scale[:, 1, 0] = gains
    U = d6[:, 2:0:-1] * scale
    Ug = U[0:6].reshape(2, 3, 2, N)
    n = np.sqrt(np.square(Ug).sum(1))
    np.maximum(n, 1e-300, out=n)
    np.divide(v_max[0:4:3, None, None], n, out=n)
    np.minimum(n, 1.0, out=n)
    Ug *= n[:, None]
    if F:
        vf = v_max[6:, None, None]
        np.maximum(U[6:], -vf, out=U[6:])
        np.minimum(U[6:], vf, out=U[6:])

    # eq (6): unit directions of [[hum - hum_prev, hum - hum_start], [cur - prev, cur - start]];
    # psi = U / v_max - u(., prev) - u(., start) + history, group by group.
    du = d[:, 1:3]
    groups = (slice(0, 3), slice(3, 6), slice(6, D))[: 3 if F else 2]
    n = np.empty((len(groups), 2, 2, N))
    for i, g in enumerate(groups):
        np.einsum("i...,i...->...", du[g], du[g], out=n[i])
    np.sqrt(n, out=n)
    eps_g = eps[[0, 3, D - 1]][: len(groups), None, None, None]
    inv = n >= eps_g
    inv = np.divide(inv, np.maximum(n, eps_g, out=n), out=n)
    psi = U / v_max[:, None, None]
    for i, g in enumerate(groups):
        psi[g] -= du[g, :, 0] * inv[i, :, 0]
        psi[g] -= du[g, :, 1] * inv[i, :, 1]
    if history is not None:
        h = np.asarray(history, dtype=np.float64)
        if h.ndim == 1:
            psi += h[:, None, None]
        else:
            psi += _rows(h, batch, (D,), N).T[:, None]

    # eq (7): normalised beta prime in |psi_human| with reference max(|psi_robot|, floor).
    ref = np.abs(psi[:, 1])
    np.maximum(ref, floor, out=ref)
    z = np.abs(psi[:, 0])
    z /= ref
    z *= p / (b * (q - 1.0))
    np.maximum(z, 1e-300, out=z)
    zm = (p - 1.0) / (q + 1.0)
    log_b = np.log(z)
    log_b *= p - 1.0
    np.log1p(z, out=z)
    z *= p + q
    log_b -= z
    log_b += (p + q) * np.log1p(zm) - (p - 1.0) * np.log(zm)
    B_raw = np.exp(log_b, out=log_b)
    return Tick(U, P, psi, B_raw, batch, A[:, :, 2, 0], left[0:3, 2, 0], left[3:, 2, 0])


def _log_pairs(A: Array, Bm: Array, out: Array) -> None:
    """so3_log(R_a R_b^T) for the pair grid, A and Bm (3, 3, 3, 2, N), into out (3, 3, 2, N)."""
    N = A.shape[-1]
    Af = A.reshape(3, 3, 6 * N)
    Bf = Bm.reshape(3, 3, 6 * N)
    of = out.reshape(3, 6 * N)
    tmp = np.empty(6 * N)
    # trace(M) = sum_ik a_ik b_ik.
    tr = Af[0, 0] * Bf[0, 0]
    for i, k in ((0, 1), (0, 2), (1, 0), (1, 1), (1, 2), (2, 0), (2, 1), (2, 2)):
        tr += np.multiply(Af[i, k], Bf[i, k], out=tmp)
    # 2 v_i = sum_k (a_(i+2)k b_(i+1)k - a_(i+1)k b_(i+2)k), i.e. m21 - m12, m02 - m20, m10 - m01.
    for i in range(3):
        j, k = (i + 1) % 3, (i + 2) % 3
        o = of[i]
        np.multiply(Af[k, 0], Bf[j, 0], out=o)
        o -= np.multiply(Af[j, 0], Bf[k, 0], out=tmp)
        for c in (1, 2):
            o += np.multiply(Af[k, c], Bf[j, c], out=tmp)
            o -= np.multiply(Af[j, c], Bf[k, c], out=tmp)
    cos_t = tr
    cos_t -= 1.0
    cos_t *= 0.5
    np.maximum(cos_t, -1.0, out=cos_t)
    np.minimum(cos_t, 1.0, out=cos_t)
    theta = np.arccos(cos_t)
    # 0.5 * theta / sin(theta), sin(theta) = sqrt((1 - c)(1 + c)) from the same c.
    s = np.subtract(1.0, cos_t, out=tmp)
    cos_t += 1.0
    s *= cos_t
    np.sqrt(s, out=s)
    np.maximum(s, 1e-300, out=s)
    np.divide(theta, s, out=s)
    s *= 0.5
    bad = np.flatnonzero((theta < _SMALL) | (theta > _NEAR_PI))
    near = bad
    if bad.size:
        # Small angles: the series of se3.so3_log; near pi: se3.so3_log on their matrices.
        th = theta[bad]
        is_small = th < _SMALL
        th = th[is_small]
        s[bad[is_small]] = 0.5 * (1.0 + th * th / 6.0)
        near = bad[~is_small]
    of *= s
    if near.size > 16:
        l_, r_, n = np.unravel_index(near, (3, 2, N))
        M = np.einsum("ikm,jkm->mij", A[:, :, l_, r_, n], Bm[:, :, l_, r_, n])
        out[:, l_, r_, n] = so3_log(M).T
    else:
        # A handful (random rotations put ~1 in 1500 pairs there): one at a time is cheaper.
        for m in near.tolist():
            of[:, m] = log_rel(Af[:, :, m].tolist(), Bf[:, :, m].tolist())


def ds_filter(
    P: Array,
    B_raw: Array,
    alpha_rows: tuple[Row, ...],
    B_rows: tuple[Row, ...],
    count: int,
    batch: tuple[int, ...],
) -> tuple[Array, Array, tuple[Row, ...], tuple[Row, ...]]:
    """Eq (8) with the moving windows (rows as `arbiters.FilterState` keeps them).

    Rows are (..., D) for the batch shape (...); the new ones are transposed views of (D, N)
    memory, so that the next tick reads them back as contiguous rows of N.

    Args:
        P: (D, 2, N) [P(H), P(R)]; B_raw: (D, N).
        alpha_rows, B_rows: W rows each in slot order (not modified); count: alpha samples
            seen before this tick.
        batch: the batch shape (...), N = prod(batch).

    Returns:
        (alpha, B, alpha_rows, B_rows): filtered (D, N) values and the new windows (this
        tick's rows in slot count % W, the others shared).
    """
    D, N = B_raw.shape
    W = len(B_rows)
    slot = count % W

    def as_dn(r: Row) -> Array:
        return np.asarray(r, dtype=np.float64).reshape(N, D).T

    def as_row(x: Array) -> Array:
        return x.T.reshape((*batch, D))

    def window_sum(rows: list[Array]) -> Array:
        total = np.array(rows[0], order="C")
        for r in rows[1:]:  # in slot order, as ndarray.sum(-2)
            total += r
        return total

    Bs = [as_dn(r) for r in B_rows]
    Bs[slot] = B_raw
    B = window_sum(Bs)
    B *= 1.0 / W
    Ph, Pr = P[:, 0], P[:, 1]
    a = np.subtract(Pr, Ph)
    a *= B
    a += Ph
    np.maximum(a, 0.0, out=a)
    np.minimum(a, 1.0, out=a)
    As = [as_dn(r) for r in alpha_rows]
    As[slot] = a
    alpha = window_sum(As)
    alpha /= min(count + 1, W)
    return (
        alpha,
        B,
        (*alpha_rows[:slot], as_row(a), *alpha_rows[slot + 1 :]),
        (*B_rows[:slot], as_row(B_raw), *B_rows[slot + 1 :]),
    )


def finish(t: Tick, alpha: Array, dt: float) -> tuple[Array, HandState]:
    """Eq (1) and (2): U_out and the integrated next state (as `se3.integrate`).

    Args:
        t: the tick; alpha: (D, N).

    Returns:
        U_out (..., D) and X_next, batch first (views of component-major arrays).
    """
    Uh, Ur = t.U[:, 0], t.U[:, 1]
    U_out = np.subtract(Ur, Uh)
    U_out *= alpha
    U_out += Uh
    D, N = U_out.shape
    nxt = np.empty((6 + D, N))  # position (3), rotation (9), openness (F), component-major
    p = nxt[0:3]
    np.multiply(U_out[0:3], dt, out=p)
    p += t.p_cur
    # exp(w) = I + a K + b K^2 = (1 - b t2) I + a K + b w w^T, K = hat(w), w = omega dt.
    w = U_out[3:6] * dt
    t2 = np.einsum("in,in->n", w, w)
    th = np.sqrt(t2)
    small = th < _SMALL
    any_small = bool(small.any())
    if any_small:
        th[small] = 1.0
    a = np.sin(th)
    a /= th
    b = np.cos(th)
    np.subtract(1.0, b, out=b)
    th *= th
    b /= th
    if any_small:
        a[small] = 1.0 - t2[small] / 6.0
        b[small] = 0.5 - t2[small] / 24.0
    E = np.multiply(w[:, None], b * w)
    aw = np.multiply(a, w, out=w)
    E[0, 1] -= aw[2]
    E[1, 0] += aw[2]
    E[0, 2] += aw[1]
    E[2, 0] -= aw[1]
    E[1, 2] -= aw[0]
    E[2, 1] += aw[0]
    b *= t2
    np.subtract(1.0, b, out=b)
    E.reshape(9, N)[::4] += b
    # R_next = E R_cur, row by row: R[i] = sum_j E[i, j] R_cur[j].
    R = nxt[3:12].reshape(3, 3, N)
    Rc = t.R_cur
    tmp = np.empty((3, N))
    for i in range(3):
        np.multiply(E[i, 0], Rc[0], out=R[i])
        R[i] += np.multiply(E[i, 1], Rc[1], out=tmp)
        R[i] += np.multiply(E[i, 2], Rc[2], out=tmp)
    g = nxt[12:]
    np.multiply(U_out[6:], dt, out=g)
    g += t.g_cur
    np.maximum(g, 0.0, out=g)
    np.minimum(g, 1.0, out=g)
    bs = t.batch
    return U_out.T.reshape((*bs, D)), HandState(
        p.T.reshape((*bs, 3)), R.transpose(2, 0, 1).reshape((*bs, 3, 3)), g.T.reshape((*bs, D - 6))
    )
