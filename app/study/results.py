"""Per-trajectory results of the study: one mode's metrics over its trials, from the batched
simulation's states and actions (`app.study.batch`); pure, no I/O.

Per trajectory the metrics of Section IV-D (dsteleop.arbitration.metrics) are taken over the
actions of the trial: cosine distance (the paper's sum over actions, the mean per action
beside it) and ratio of agreement of U_human vs U_out, both skipping the same idle actions
(`metrics.idle_actions`); the paper's definitions in the arbitration's units (m/s, rad/s) are
the headline, and `VARIANTS` adds actions over the velocity limits, per group and a labelled
dead-band variant; by phase of the trial (deciles of its duration) and while the operator
moves along y only (the paper's Fig. 5 remark) beside them. Success and time as the world
defines them (`app.study.planar`). Results of chunks of trajectories concatenate in index
order (`merge`), so pooled sums do not depend on how the rows were chunked; the summary over
trajectories is `app.study.summary`.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.study.inference import ObjectRows
from dsteleop.app.study.metric_table import Trials, table, variant_key
from dsteleop.app.study.planar import Array, SimConfig, in_success_region
from dsteleop.arbitration import metrics
from dsteleop.arbitration.se3 import ROT, TRANS
from dsteleop.errors import ContractError

DEAD_BAND_MPS = 0.001  # the dead-band variant skips output actions slower than this [m/s]
HIST_BINS = 16
PATH_STRIDE = 3  # keep every 3rd tick of the example paths (Fig. 5b)
PHASE_EDGES = np.linspace(0.0, 1.0, 11)  # deciles of each trial for the by-phase metrics
Y_ONLY_MPS = 0.02  # operator speed along y above which a y-only action counts [m/s]


@dataclass(frozen=True)
class ModeResult:
    """Per-trajectory results of one mode over a set of trajectories (arrays (N,))."""

    success: NDArray[np.bool_]
    time_s: Array
    cosine_mean: Array
    cosine_sum: Array
    agreement: Array
    n_actions: NDArray[np.int64]
    final: Array  # (N, 3) final x, y, heading of the robot
    hist: NDArray[np.int64]  # 3-D histogram of the robot's (x, y, heading) over all ticks
    paths: Array  # (P, T', 3) robot (x, y, heading) of the first trajectories, padded with nan
    phase_cos: Array  # (N, 2, bins) sum and count of the cosine distance per phase bin
    phase_agree: Array  # (N, 2, bins) agreements and actions per phase bin
    y_only: Array  # (N, 3) sum |U_out_x|, sum |U_out_y|, actions while the operator moves y only
    lengths: NDArray[np.int64]  # (N,) states of each trial (closed loop: mode-dependent)
    gave_up: NDArray[np.bool_]  # (N,) the closed-loop operator gave up (False for open loop)
    n_idle: NDArray[np.int64]  # (N,) idle actions, skipped by both cosine distance and agreement
    hand_hist: NDArray[np.int64]  # the hand's (x, y, heading) histogram in this mode
    hand_paths: Array  # (P, T', 3) the hand's paths of the first trajectories
    variants: dict[str, Array]  # per-trajectory metric variants (`metric_variants`)
    values: dict[str, Array]  # (N,) per metric of the table and its variant (`study_values`)
    committed: NDArray[np.bool_]  # (N,) the closed-loop operator committed (True for open loop)
    hand_final: Array  # (N, 3) the hand's final x, y, heading
    attempt: NDArray[np.int64]  # (N,) the run of each row (0 first)
    history_norm: Array  # (N,) |eq (6)'s history term| (L1) the run's arbitration received
    settled: NDArray[np.bool_]  # (N,) the closed-loop operator settled (the task's or robot's way)
    # The objects world (`app.study.inference.ObjectRows`; -1, False, NaN in the others):
    wanted: NDArray[np.intp]  # (N,) the object the person wanted at the end of its run
    changed: NDArray[np.bool_]  # (N,) the person changed its mind during the run
    grasped: NDArray[np.intp]  # (N,) the object within R of the settled pose (-1: none)
    map_final: NDArray[np.intp]  # (N,) the robot's MAP object at the end
    map_switches: NDArray[np.int64]  # (N,) how often the MAP changed during the run
    map_settled_s: Array  # (N,) since when the MAP was the wanted object [s] (NaN: not at the end)


#: ModeResult's fields that are not one row per trial (summed or kept for the first paths).
_POOLED = ("hist", "paths", "hand_hist", "hand_paths")
#: ModeResult's fields that are dicts of rows (one array per name).
_BY_NAME = ("variants", "values")


def concat_results(parts: Sequence[ModeResult]) -> ModeResult:
    """The rows of `parts` one after the other (histograms summed, paths concatenated)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(ModeResult):
        vals = [getattr(p, f.name) for p in parts]
        if f.name in ("hist", "hand_hist"):
            out[f.name] = np.sum(vals, axis=0)
        elif f.name in ("paths", "hand_paths"):
            out[f.name] = _cat_paths(vals)
        elif f.name in _BY_NAME:
            out[f.name] = {k: np.concatenate([v[k] for v in vals]) for k in vals[0]}
        else:
            out[f.name] = np.concatenate(vals)
    return ModeResult(**out)


def take_rows(r: ModeResult, order: NDArray[np.intp]) -> ModeResult:
    """The rows `order` of r (the pooled fields as they are)."""
    out: dict[str, Any] = {}
    for f in dataclasses.fields(ModeResult):
        v = getattr(r, f.name)
        if f.name in _POOLED:
            out[f.name] = v
        elif f.name in _BY_NAME:
            out[f.name] = {k: x[order] for k, x in v.items()}
        else:
            out[f.name] = v[order]
    return ModeResult(**out)


def _cat_paths(arrs: Sequence[Array]) -> Array:
    arrs = [a for a in arrs if a.shape[0] > 0]
    if not arrs:
        return np.zeros((0, 1, 3))
    T = max(a.shape[1] for a in arrs)
    return np.concatenate(
        [np.pad(a, ((0, 0), (0, T - a.shape[1]), (0, 0)), constant_values=np.nan) for a in arrs]
    )


@dataclass(frozen=True)
class ChunkResult:
    """Results of a contiguous set of trajectories under every mode: `runs` rows per
    trajectory in the modes' results (row n * runs + a: run a of trajectory n)."""

    indices: NDArray[np.int64]
    lengths: NDArray[np.int64]
    lead: NDArray[np.bool_]
    operator_hist: NDArray[np.int64]
    operator_paths: Array
    modes: dict[str, ModeResult]


def mode_result(
    cfg: SimConfig,
    poses_tm: Array,
    lengths: NDArray[np.int64],
    hand_tm: Array,
    gave_up: NDArray[np.bool_],
    committed: NDArray[np.bool_],
    U_h_tm: Array,
    U_out_tm: Array,
    acted_tm: NDArray[np.bool_],
    ranges: Array,
    n_paths: int,
    attempt: int = 0,
    history_norm: Array | None = None,
    settled: NDArray[np.bool_] | None = None,
    objects: ObjectRows | None = None,
) -> ModeResult:
    """One mode's per-trajectory results from its robot's and hand's states (T, N, 3) and
    its actions (T - 1, N, ...), time-major. A closed-loop trial succeeds only if its operator
    committed and the robot's settled pose (the trial's last) is in the success region (in
    the objects world, `objects`: the region of the object its person wanted at the end)."""
    T, N = poses_tm.shape[:2]
    # (N, T, ...) views, as for the actions below.
    poses, hand = np.swapaxes(poses_tm, 0, 1), np.swapaxes(hand_tm, 0, 1)
    # (N, T - 1, ...) views: the metrics reduce over the time axis wherever it lies in memory.
    U_h_all, U_out_all = np.swapaxes(U_h_tm, 0, 1), np.swapaxes(U_out_tm, 0, 1)
    acted = acted_tm.T
    # The actions' products per group (translation, rotation: the planar study has no
    # fingers), computed once; the literal definitions (the headline) weigh both alike.
    groups = metrics.ActionProducts.of_groups(U_h_all, U_out_all, (TRANS, ROT))
    lit = metrics.ActionProducts.combine(groups, (1.0, 1.0))
    c = metrics.cosine_distances(lit)
    cos = metrics.summarise_cosines(c, acted)
    ag = metrics.agreement_of(lit, acted)
    # By phase of the trial: tick k of a trial of L ticks is at phase k / (L - 1).
    n_bins = len(PHASE_EDGES) - 1
    k = np.arange(T - 1)[None, :]
    phase = k / (lengths[:, None] - 1)
    b = np.clip(np.searchsorted(PHASE_EDGES, phase, side="right") - 1, 0, n_bins - 1)
    counted = acted & ~np.isnan(c)  # the actions both metrics count (not idle)
    agrees = counted & (lit.dot > 0.0)
    # Per trajectory (N, 2, bins), so pooled sums do not depend on how rows were chunked.
    cos_bins = _bin_sum(b, np.where(counted, c, 0.0), n_bins)
    ph_cos = np.stack([cos_bins, _bin_sum(b, counted, n_bins)], 1)
    ph_ag = np.stack([_bin_sum(b, agrees, n_bins), _bin_sum(b, counted, n_bins)], 1)
    # Operator moving along y only (|v_x| < 0.1 |v_y|, |v_y| > 0.02 m/s): how much x does the
    # output add (the paper's Fig. 5 narrative)?
    vx, vy = np.abs(U_h_all[..., 0]), np.abs(U_h_all[..., 1])
    y_only = acted & (vy > Y_ONLY_MPS) & (vx < 0.1 * vy)
    cross = np.stack(
        [
            np.where(y_only, np.abs(U_out_all[..., 0]), 0.0).sum(1),
            np.where(y_only, np.abs(U_out_all[..., 1]), 0.0).sum(1),
            y_only.sum(1).astype(np.float64),
        ],
        -1,
    )
    valid = np.arange(T)[None, :] < lengths[:, None]
    rows = np.arange(N)
    last = lengths - 1

    handle: Array | tuple[float, float] = cfg.handle_xy_m
    if objects is not None:
        handle = objects.true_xy[objects.wanted]

    def inside(p: Array) -> NDArray[np.bool_]:
        return in_success_region(
            p[..., :2], p[..., 2], handle, cfg.grasp_headings,
            cfg.success_radius_m, cfg.success_heading_rad,
        )  # fmt: skip

    if cfg.closed_loop:  # the operator decides when the trial is done: its settled pose
        success = inside(poses[rows, last]) & committed
        time_s = np.maximum(last, 1) * cfg.dt_s
    else:  # settling time: the first tick after the last one outside the region
        inside_all = inside(poses)
        success = inside_all[rows, last] & committed
        outside = valid & ~inside_all
        last_out = np.where(outside.any(1), T - 1 - np.argmax(outside[:, ::-1], axis=1), -1)
        settle = (last_out + 1) * cfg.dt_s
        time_s = np.where(success, np.maximum(settle, cfg.dt_s), last * cfg.dt_s)
    hand_valid = valid.T & np.isfinite(hand_tm[..., 0])  # time-major
    return ModeResult(
        success=success,
        time_s=time_s,
        cosine_mean=cos.mean,
        cosine_sum=cos.total,
        agreement=ag.ratio,
        n_actions=cos.n_actions,
        final=poses[rows, last],
        hist=metrics.trajectory_histogram(poses_tm[valid.T], HIST_BINS, ranges),
        paths=_paths(poses[:n_paths], lengths[:n_paths]),
        phase_cos=ph_cos,
        phase_agree=ph_ag,
        y_only=cross,
        lengths=lengths,
        gave_up=gave_up,
        n_idle=cos.n_skipped,
        hand_hist=metrics.trajectory_histogram(hand_tm[hand_valid], HIST_BINS, ranges),
        hand_paths=_paths(hand[:n_paths], lengths[:n_paths]),
        variants=_variants(cfg, groups, acted, lit, c),
        values=study_values(
            Trials(success, time_s, U_h_all, U_out_all, acted, cos.total, cos.mean, ag.ratio)
        ),
        committed=committed,
        hand_final=hand[rows, last],
        attempt=np.full(N, attempt, dtype=np.int64),
        history_norm=np.zeros(N) if history_norm is None else history_norm,
        settled=np.zeros(N, dtype=bool) if settled is None else settled,
        **_object_fields(cfg, poses[rows, last], objects, N),
    )


def _object_fields(
    cfg: SimConfig, final: Array, objects: ObjectRows | None, N: int
) -> dict[str, Any]:
    """ModeResult's objects-world fields: the wanted object, the change of mind, the object
    within the success radius of the settled pose `final` (N, 3) (-1: none) and the MAP's
    statistics; neutral values in the other worlds."""
    if objects is None:
        none = np.full(N, -1, dtype=np.intp)
        return {
            "wanted": none, "changed": np.zeros(N, dtype=bool), "grasped": none,
            "map_final": none, "map_switches": np.zeros(N, dtype=np.int64),
            "map_settled_s": np.full(N, np.nan),
        }  # fmt: skip
    d = np.linalg.norm(final[:, None, :2] - objects.true_xy[None], axis=-1)  # (N, K)
    near = np.argmin(d, axis=1)
    grasped = np.where(d[np.arange(N), near] <= cfg.success_radius_m, near, -1)
    return {
        "wanted": objects.wanted, "changed": objects.changed, "grasped": grasped,
        "map_final": objects.map.final, "map_switches": objects.map.switches,
        "map_settled_s": objects.map.settled_s,
    }  # fmt: skip


def study_values(trials: Trials) -> dict[str, Array]:
    """Per trajectory, the value of every metric of the table and of its variant (keyed by
    `variant_key`), from one mode's trials."""
    out: dict[str, Array] = {}
    for m in table():
        out[m.name] = np.asarray(m.study(trials))
        if m.variant is not None:
            out[variant_key(m)] = np.asarray(m.variant.study(trials))
    return out


VARIANTS = {
    "normalised": "actions divided by the velocity limits (metres and radians weigh alike)",
    "translation": "the translation group only (x, y; m/s)",
    "rotation": "the rotation group only (heading; rad/s)",
    "dead_band": (
        "LABELLED VARIANT: the literal definitions, skipping actions where the robot's output "
        "is under 1 mm/s and 1 mrad/s (a parked robot copying a vanishing share of the hand "
        "no longer counts as agreeing)"
    ),
}


def _variants(
    cfg: SimConfig,
    groups: Sequence[metrics.ActionProducts],
    acted: NDArray[np.bool_],
    literal: metrics.ActionProducts,
    literal_cos: Array,
) -> dict[str, Array]:
    """Per-trajectory cosine distance and agreement under the definitions of VARIANTS; each
    is the literal metric on re-weighted dimensions or a narrower set of actions. `groups`:
    the actions' products of the translation and of the rotation group."""
    trans, rot = groups
    # Divided by the velocity limits: one limit per group (v_max_mps, w_max_radps).
    a = cfg.arbitration
    norm = metrics.ActionProducts.combine(
        groups, (1.0 / (a.v_max_mps * a.v_max_mps), 1.0 / (a.w_max_radps * a.w_max_radps))
    )
    # The output under 1 mm/s and 1 mrad/s (the planar robot turns about z only).
    still = (trans.oo < DEAD_BAND_MPS**2) & (rot.oo < DEAD_BAND_MPS**2)
    out: dict[str, Array] = {}
    for name, p, c, mask in (
        ("normalised", norm, None, acted),
        ("translation", trans, None, acted),
        ("rotation", rot, None, acted),
        ("dead_band", literal, literal_cos, acted & ~still),
    ):
        cos = metrics.cosine_distances(p) if c is None else c
        out[f"{name}.cosine_distance"] = metrics.summarise_cosines(cos, mask).mean
        out[f"{name}.agreement"] = metrics.agreement_of(p, mask).ratio
    return out


def _bin_sum(bins: NDArray[np.intp], weights: NDArray[np.float64 | np.bool_], n_bins: int) -> Array:
    """Per row, the sums of `weights` (N, T) over the bins (N, T) -> (N, n_bins)."""
    N = bins.shape[0]
    flat = (np.arange(N)[:, None] * n_bins + bins).ravel()
    w = np.asarray(weights, dtype=np.float64).ravel()
    return np.asarray(np.bincount(flat, w, N * n_bins), dtype=np.float64).reshape(N, n_bins)


def _paths(poses: Array, lengths: NDArray[np.int64]) -> Array:
    p = poses[:, ::PATH_STRIDE].copy()
    keep = np.arange(p.shape[1])[None, :] * PATH_STRIDE < lengths[:, None]
    p[~keep] = np.nan
    return p


@dataclass(frozen=True)
class StudyResult:
    """All trajectories of a study, merged from chunks in index order."""

    config: SimConfig
    lengths: NDArray[np.int64]
    lead: NDArray[np.bool_]
    operator_hist: NDArray[np.int64]
    operator_paths: Array
    modes: dict[str, ModeResult]


def merge(cfg: SimConfig, chunks: Sequence[ChunkResult]) -> StudyResult:
    """Concatenate chunk results in trajectory order (chunks may arrive in any order)."""
    ordered = sorted(chunks, key=lambda c: int(c.indices[0]))
    idx = np.concatenate([c.indices for c in ordered])
    if not np.array_equal(idx, np.arange(cfg.trajectories)):
        raise ContractError("chunks do not cover the trajectories exactly once")

    modes = {m.value: concat_results([c.modes[m.value] for c in ordered]) for m in cfg.modes}
    return StudyResult(
        config=cfg,
        lengths=np.concatenate([c.lengths for c in ordered]),
        lead=np.concatenate([c.lead for c in ordered]),
        operator_hist=np.sum([c.operator_hist for c in ordered], axis=0),
        operator_paths=_cat_paths([c.operator_paths for c in ordered]),
        modes=modes,
    )
