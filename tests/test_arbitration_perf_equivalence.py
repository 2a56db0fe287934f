"""The fast paths (scalar.py for one state, batched.py for a batch) against a plain reference.

The reference below is the straightforward numpy reading of eq (1)-(8): `se3.diff` (matmul and
`so3_log`), `saturate`, `integrate` and the functions of `allocation.py`, stacked exactly as
the first implementation of the arbiters did. Both fast paths must match it to 1e-9 in every
mode, on random inputs and on the edge cases the fast paths branch on (zero motion below eps,
small angles, angles near pi, no fingers, a history term, broadcast and nested batch shapes,
several DS ticks through the moving windows).

One limit is the maths, not the code: within ~1e-3 rad of pi, so3_log takes theta / sin(theta)
from the trace, whose rounding is amplified by 1 / sin(theta)^2 (~1e6 there); any two orders of
summation (BLAS matmul vs explicit sums) then differ by ~1e-10 in the rotation vector, and
exactly at pi the sign of the rotation vector is arbitrary. The near-pi cases below stay a few
1e-6 rad inside the near-pi branch, where the axis comes from the symmetric part and is exact.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from dsteleop.arbitration import (
    STEP_ARRAYS,
    ArbitrationConfig,
    ArbitrationInput,
    HandState,
    Mode,
    diff,
    integrate,
    make_arbiter,
    saturate,
    so3_exp,
    so3_log,
)
from dsteleop.arbitration.allocation import (
    ds_alpha,
    expected_allocation,
    standard_alpha,
    unit_directions,
    willingness,
)
from dsteleop.arbitration.arbiters import FilterState

from .strategies import arbitration_inputs, input_from_states, stack_inputs

FIELDS: tuple[str, ...] = STEP_ARRAYS
NAMES = ("X_human", "X_human_prev", "X_human_start", "X_current", "X_prev", "X_start", "X_goal")


def reference_step(
    mode: Mode, cfg: ArbitrationConfig, state: FilterState, inp: ArbitrationInput
) -> tuple[FilterState, dict[str, NDArray[np.float64]]]:
    """The plain numpy reading of one tick (any batch shape, broadcasting states)."""
    H, Hp, Hs = inp.X_human, inp.X_human_prev, inp.X_human_start
    C, Cp, Cs, G = inp.X_current, inp.X_prev, inp.X_start, inp.X_goal
    F = C.n_fingers
    gains, v_max, eps = cfg.gains(F), cfg.v_max(F), cfg.eps(F)
    U_r = saturate(gains * diff(G, C), v_max)
    U_h = saturate(diff(H, Hp) / inp.dt, v_max)
    d_gs = diff(G, Cs)
    P_r = expected_allocation(diff(G, C), d_gs, eps, cfg.kappa)
    P_h = expected_allocation(diff(G, H), d_gs, eps, cfg.kappa)
    hist = 0.0 if inp.history_term is None else inp.history_term
    psi_r = U_r / v_max - unit_directions(diff(C, Cp), eps) - unit_directions(diff(C, Cs), eps)
    psi_h = U_h / v_max - unit_directions(diff(H, Hp), eps) - unit_directions(diff(H, Hs), eps)
    psi_r, psi_h = psi_r + hist, psi_h + hist
    B = willingness(psi_h, psi_r, cfg.p, cfg.q, cfg.b, cfg.psi_robot_floor)
    shape = np.broadcast_shapes(U_r.shape, U_h.shape, P_r.shape, P_h.shape, psi_r.shape)
    if mode is Mode.DS:
        W = state.B_buf.shape[-2]
        slot = state.count % W
        B_buf = state.B_buf.copy()
        B_buf[..., slot, :] = B
        B = B_buf.sum(-2) / W
        alpha_buf = state.alpha_buf.copy()
        alpha_buf[..., slot, :] = ds_alpha(P_r, P_h, B)
        alpha = alpha_buf.sum(-2) / min(state.count + 1, W)
        state = FilterState.from_buffers(alpha_buf, B_buf, state.count + 1)
    elif mode is Mode.S:
        a = standard_alpha(G.position, C.position, Cs.position, cfg.eps_trans_m)
        alpha = np.broadcast_to(a[..., None], shape)
    else:
        alpha = np.full(shape, 1.0 if mode is Mode.AUTONOMOUS else 0.0)
    U_out = U_h + alpha * (U_r - U_h)
    X = integrate(C, U_out, inp.dt)
    out = dict(alpha=alpha, P_human=P_h, P_robot=P_r, B=B, psi_human=psi_h, psi_robot=psi_r)
    out.update(U_human=U_h, U_robot=U_r, U_out=U_out)
    out.update(position=X.position, rotation=X.rotation, openness=X.openness)
    return state, out


def assert_matches(
    mode: Mode,
    inp: ArbitrationInput,
    cfg: ArbitrationConfig | None = None,
    ticks: int = 1,
    batch: tuple[int, ...] = (),
    atol: float = 1e-9,
) -> None:
    """Step the arbiter and the reference side by side and compare everything."""
    cfg = cfg or ArbitrationConfig()
    arb = make_arbiter(mode, cfg)
    D = 6 + inp.X_current.n_fingers
    fs = ref = arb.initial_state(D, batch)
    for _ in range(ticks):
        fs, r = arb.step(fs, inp)
        ref, expected = reference_step(mode, cfg, ref, inp)
        for name in FIELDS:
            got = getattr(r, name)
            assert got.shape == expected[name].shape, name
            np.testing.assert_allclose(got, expected[name], rtol=0, atol=atol, err_msg=name)
        for name in ("position", "rotation", "openness"):
            got = getattr(r.X_next, name)
            np.testing.assert_allclose(got, expected[name], rtol=0, atol=atol, err_msg=name)
        np.testing.assert_allclose(fs.alpha_buf, ref.alpha_buf, rtol=0, atol=atol)
        np.testing.assert_allclose(fs.B_buf, ref.B_buf, rtol=0, atol=atol)
        assert fs.count == ref.count


def random_state(rng: np.random.Generator, batch: tuple[int, ...], F: int) -> HandState:
    return HandState(
        rng.uniform(-0.5, 0.5, (*batch, 3)),
        so3_exp(rng.normal(0.0, 1.5, (*batch, 3))),
        rng.uniform(0.0, 1.0, (*batch, F)),
    )


def random_input(
    rng: np.random.Generator, batch: tuple[int, ...], F: int, history: bool = False
) -> ArbitrationInput:
    s = [random_state(rng, batch, F) for _ in NAMES]
    h = rng.normal(0.0, 0.3, 6 + F) if history else None
    return input_from_states(s, 1.0 / 30.0, h)


# --- random inputs, every mode, single and batched ---------------------------------------


@pytest.mark.parametrize("mode", list(Mode))
@given(inp=arbitration_inputs(), history=st.booleans(), window=st.integers(1, 4))
@settings(max_examples=60)
def test_single_step_matches_reference(
    mode: Mode, inp: ArbitrationInput, history: bool, window: int
) -> None:
    if history:
        h = np.linspace(-0.4, 0.4, 11)
        inp = input_from_states([getattr(inp, n) for n in NAMES], inp.dt, h)
    assert_matches(mode, inp, ArbitrationConfig(window=window), ticks=window + 2)


@pytest.mark.parametrize("mode", list(Mode))
@given(inputs=st.lists(arbitration_inputs(), min_size=1, max_size=5))
@settings(max_examples=40)
def test_batched_step_matches_reference(mode: Mode, inputs: list[ArbitrationInput]) -> None:
    inp = stack_inputs(inputs)
    assert_matches(mode, inp, ArbitrationConfig(window=3), ticks=4, batch=(len(inputs),))


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("F", [0, 1, 4])
@pytest.mark.parametrize("batch", [(), (1,), (257,), (3, 2)])
def test_shapes_fingers_and_history(mode: Mode, F: int, batch: tuple[int, ...]) -> None:
    rng = np.random.default_rng(F + 7 * len(batch))
    for history in (False, True):
        inp = random_input(rng, batch, F, history)
        assert_matches(mode, inp, ArbitrationConfig(window=2), ticks=3, batch=batch)


# --- edge cases the fast paths branch on -------------------------------------------------


def _with(inp: ArbitrationInput, **states: HandState) -> ArbitrationInput:
    kw = {n: getattr(inp, n) for n in NAMES}
    kw.update(states)
    return ArbitrationInput(**kw, dt=inp.dt, history_term=inp.history_term)


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("batch", [(), (64,)])
def test_holding_still_small_angles_and_eps(mode: Mode, batch: tuple[int, ...]) -> None:
    """No motion (unit directions 0 below eps), tiny rotations (series branch), B = 0."""
    rng = np.random.default_rng(2)
    inp = random_input(rng, batch, 5)
    H, C = inp.X_human, inp.X_current
    tiny = HandState(
        H.position + rng.normal(0, 3e-4, H.position.shape),
        so3_exp(rng.normal(0, 2e-5, H.position.shape)) @ H.rotation,
        H.openness + rng.normal(0, 3e-4, H.openness.shape),
    )
    assert_matches(mode, _with(inp, X_human_prev=H, X_prev=C, X_start=C), ticks=2, batch=batch)
    assert_matches(mode, _with(inp, X_human_prev=tiny, X_human_start=tiny), batch=batch)
    assert_matches(mode, _with(inp, X_goal=C, X_human=C, X_human_prev=C), batch=batch)


def _near_pi_from(
    R: NDArray[np.float64], rng: np.random.Generator, gap: float
) -> NDArray[np.float64]:
    """Rotations at pi - gap from R (R_b such that log(R R_b^T) has angle pi - gap)."""
    axis = rng.normal(size=(*R.shape[:-2], 3))
    axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
    return np.swapaxes(so3_exp(axis * (np.pi - gap)), -1, -2) @ R


@pytest.mark.parametrize("mode", list(Mode))
@pytest.mark.parametrize("batch", [(), (5,), (400,)])
def test_rotations_near_pi(mode: Mode, batch: tuple[int, ...]) -> None:
    """Relative rotations in the near-pi branch of so3_log (a few, and many in one batch)."""
    rng = np.random.default_rng(3)
    inp = random_input(rng, batch, 4)
    H, C, G = inp.X_human, inp.X_current, inp.X_goal
    for gap in (5e-6, 2e-4):
        flip = {
            "X_human_prev": HandState(H.position, _near_pi_from(H.rotation, rng, gap), H.openness),
            "X_prev": HandState(C.position, _near_pi_from(C.rotation, rng, gap), C.openness),
            "X_current": HandState(C.position, _near_pi_from(G.rotation, rng, gap), C.openness),
        }
        assert_matches(mode, _with(inp, **flip), batch=batch)


def test_so3_log_matches_one_by_one_and_scalar_near_pi() -> None:
    rng = np.random.default_rng(4)
    R = so3_exp(rng.normal(0, 1, (300, 3)))
    R[::3] = _near_pi_from(np.eye(3), rng, 1e-6)[None]
    R[1::7] = so3_exp(rng.normal(0, 1e-5, (43, 3)))
    batched = so3_log(R)
    single = np.array([so3_log(r) for r in R])
    np.testing.assert_array_equal(batched, single)
    assert so3_log(R.reshape(30, 10, 3, 3)).shape == (30, 10, 3)


@pytest.mark.parametrize("mode", list(Mode))
def test_broadcast_batch_shapes(mode: Mode) -> None:
    """An unbatched goal and start with batched hands, as numpy broadcasting allows."""
    rng = np.random.default_rng(5)
    inp = random_input(rng, (6,), 5, history=True)
    one = random_input(rng, (), 5)
    inp = _with(inp, X_goal=one.X_goal, X_start=one.X_start, X_human_start=one.X_human_start)
    assert_matches(mode, inp, ticks=2, batch=(6,))


# --- the two paths together, and value semantics ----------------------------------------


@pytest.mark.parametrize("mode", list(Mode))
def test_closed_loop_single_and_batched_agree(mode: Mode) -> None:
    """X_next fed back for 40 ticks: three single loops equal one batched loop of three."""
    rng = np.random.default_rng(6)
    arb = make_arbiter(mode, ArbitrationConfig(window=4))
    goals = [random_state(rng, (), 4) for _ in range(3)]
    hands = [[random_state(rng, (), 4) for _ in range(41)] for _ in range(3)]
    start = [random_state(rng, (), 4) for _ in range(3)]
    X = list(start)
    Xp = list(start)
    fs = [arb.initial_state(10) for _ in range(3)]
    Xb = stack_inputs([input_from_states([s] * 7, 0.05) for s in start]).X_current
    Xbp = Xb
    fsb = arb.initial_state(10, (3,))
    for k in range(40):
        inputs = [
            ArbitrationInput(
                hands[i][k + 1], hands[i][k], hands[i][0], X[i], Xp[i], start[i], goals[i], 0.05
            )
            for i in range(3)
        ]
        results = []
        for i in range(3):
            fs[i], r = arb.step(fs[i], inputs[i])
            Xp[i], X[i] = X[i], r.X_next
            results.append(r)
        stacked = stack_inputs(inputs)
        binp = _with(stacked, X_current=Xb, X_prev=Xbp)
        fsb, rb = arb.step(fsb, binp)
        Xbp, Xb = Xb, rb.X_next
        for i in range(3):
            for name in FIELDS:
                np.testing.assert_allclose(
                    getattr(results[i], name), getattr(rb, name)[i], rtol=0, atol=1e-9
                )
            np.testing.assert_allclose(X[i].rotation, Xb.rotation[i], rtol=0, atol=1e-9)


@pytest.mark.parametrize("batch", [(), (8,)])
def test_step_leaves_its_inputs_and_old_state_alone(batch: tuple[int, ...]) -> None:
    rng = np.random.default_rng(7)
    inp = random_input(rng, batch, 5, history=True)
    copies = {n: [a.copy() for a in vars(getattr(inp, n)).values()] for n in NAMES}
    arb = make_arbiter(Mode.DS)
    fs0 = arb.initial_state(11, batch)
    fs1, r1 = arb.step(fs0, inp)
    np.testing.assert_array_equal(fs0.B_buf, 1.0)
    np.testing.assert_array_equal(fs0.alpha_buf, 0.0)
    assert fs0.count == 0
    for n in NAMES:
        for a, b in zip(vars(getattr(inp, n)).values(), copies[n]):
            np.testing.assert_array_equal(a, b)
    # Writing into a result changes no state; stepping a state leaves it as it was (the new
    # state shares the untouched window rows), so an old state can be stepped again.
    windows = (fs1.alpha_buf, fs1.B_buf)
    for name in FIELDS:
        getattr(r1, name)[...] = -1.0
    fs2, r2 = arb.step(fs1, inp)
    assert np.all(r2.alpha >= 0.0)
    np.testing.assert_array_equal(fs1.alpha_buf, windows[0])
    np.testing.assert_array_equal(fs1.B_buf, windows[1])
    fs2b, r2b = arb.step(fs1, inp)
    np.testing.assert_array_equal(r2b.alpha, r2.alpha)
    np.testing.assert_array_equal(fs2b.B_buf, fs2.B_buf)
    assert r2.alpha.shape == (*batch, 11) and r2.X_next.rotation.shape == (*batch, 3, 3)


def test_batched_filter_state_with_unbatched_inputs_broadcasts() -> None:
    """A DS filter state of batch (3,) with single inputs: three copies of the single tick."""
    rng = np.random.default_rng(8)
    inp = random_input(rng, (), 5)
    arb = make_arbiter(Mode.DS)
    fs1, fs3 = arb.initial_state(11), arb.initial_state(11, (3,))
    for _ in range(3):
        fs1, r1 = arb.step(fs1, inp)
        fs3, r3 = arb.step(fs3, inp)
        for name in FIELDS:
            got, want = getattr(r3, name), getattr(r1, name)
            np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=0, atol=1e-9)
    with pytest.raises(ValueError, match="filter state"):
        arb.step(arb.initial_state(11), random_input(rng, (2,), 5))


@pytest.mark.parametrize("batch", [(), (6,), (2, 3)])
def test_filter_state_from_buffers_and_select(batch: tuple[int, ...]) -> None:
    """A window rebuilt from its (..., W, D) arrays steps like the original; select() keeps rows."""
    rng = np.random.default_rng(9)
    arb = make_arbiter(Mode.DS)
    fs = arb.initial_state(11, batch)
    for _ in range(3):
        fs, _ = arb.step(fs, random_input(rng, batch, 5))
    assert fs.alpha_buf.shape == fs.B_buf.shape == (*batch, 5, 11)
    copy = FilterState.from_buffers(fs.alpha_buf, fs.B_buf, fs.count)
    inp = random_input(rng, batch, 5)
    (a, ra), (b, rb) = arb.step(fs, inp), arb.step(copy, inp)
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(ra, name), getattr(rb, name))
    np.testing.assert_array_equal(a.alpha_buf, b.alpha_buf)
    np.testing.assert_array_equal(a.B_buf, b.B_buf)
    if len(batch) == 1:
        keep = np.arange(batch[0]) % 2 == 0
        part = a.select(keep)
        assert part.count == a.count
        np.testing.assert_array_equal(part.alpha_buf, a.alpha_buf[keep])
        np.testing.assert_array_equal(part.B_buf, a.B_buf[keep])
        kept = [getattr(inp, n) for n in NAMES]
        kept = [HandState(s.position[keep], s.rotation[keep], s.openness[keep]) for s in kept]
        _, r_part = arb.step(part, input_from_states(kept, inp.dt))
        _, r_all = arb.step(a, inp)
        np.testing.assert_allclose(r_part.alpha, r_all.alpha[keep], rtol=0, atol=1e-12)
