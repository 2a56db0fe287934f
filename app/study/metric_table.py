"""The metric table: every metric a run is judged by, declared once and read by the study, its
summary and report, tuning (objective, trials, hold-out, reports, figures) and replay.

A metric (`Metric`) is one number per trial (a trajectory of the study, an episode of a
replay) with a name, a label, a unit, a direction and a scale; the scale says how every
consumer summarises it over trials and tests two modes on it:

    rate     a 0/1 outcome per trial: the share as a Laplace estimate with the adjusted-Wald
             interval (`<name>_rate`); McNemar's test of paired outcomes and the N-1
             chi-squared test; a gain is a paired difference of shares
    log      a positive value (a time): the geometric mean with the interval of the log mean;
             t tests of the logs (`log_<short>`); a gain is a ratio of geometric means
    linear   a value per trial (an action metric): the paper's Table I summarises it by the
             geometric mean too (the study and replay tables); tuning by the arithmetic mean
             with its t interval; t tests of the values; a gain is a paired difference

Each metric says how a trial's value is taken: `study` from one mode's trials of the study
(`Trials`: per trajectory arrays, the actions included), `replay` from one replayed run (a
`Trace`, its arbitrated ticks, actions in units of the velocity limits). A metric may carry one
labelled variant (`Variant`: the cosine distance's mean per action beside the paper's sum),
reported and tested beside it; with `tune_variant` tuning optimises the variant.

The table is the paper's Section IV-D (docs/METHOD.md §7) in Table I's order: success rate,
trial time, cosine distance, ratio of agreement. `register` adds a metric (and `unregister`
removes it): it then reaches every consumer (tests/test_metric_table.py); a consumer may add
details of its own to the metrics it knows (the study's censored times, replay's outcome).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dsteleop.app.jsonable import finite
from dsteleop.app.session.trace import Trace
from dsteleop.arbitration import metrics
from dsteleop.errors import ConfigError

Array = NDArray[np.float64]
Scale = Literal["rate", "log", "linear"]
SCALES: tuple[str, ...] = ("rate", "log", "linear")


@dataclass(frozen=True)
class Trials:
    """One mode's trials in the study, what a metric's `study` reads (N trials).

    Attributes:
        success: (N,) the trial succeeded.
        time_s: (N,) its time [s] (docs/sim.md).
        U_human, U_out: (N, T - 1, 6) the hand's and the output's actions per tick, in the
            arbitration's units (m/s, rad/s); only where `acted` are they the trial's.
        acted: (N, T - 1) the tick belongs to the trial.
        cosine_sum, cosine_mean: (N,) the cosine distance summed over the actions and per
            action (idle actions skipped).
        agreement: (N,) the ratio of agreement (idle actions skipped).
    """

    success: NDArray[np.bool_]
    time_s: Array
    U_human: Array
    U_out: Array
    acted: NDArray[np.bool_]
    cosine_sum: Array
    cosine_mean: Array
    agreement: Array


@dataclass(frozen=True)
class Variant:
    """A labelled second definition of a metric, reported and tested beside it.

    Attributes:
        suffix: its name after the metric's (`cosine_distance` + `per_action_mean`).
        label: what it is, stated in the outputs (LABELLED VARIANT: ...).
        study: its value per trajectory.
        replay: its value of one replayed run (None: none).
    """

    suffix: str
    label: str
    study: Callable[[Trials], NDArray[Any]]
    replay: Callable[[Trace], Any]


@dataclass(frozen=True)
class Metric:
    """One metric (module docstring).

    Attributes:
        name: its key in every output (`<source>.<MODE>.<name>` in tuning, a field of a
            replay's run and of the study's summary per mode).
        label: words for tables and sentences ("ratio of agreement").
        unit: its unit, "" when it has none.
        maximise: more is better (else less is).
        scale: `rate`, `log` or `linear` (module docstring).
        study: its value per trajectory of the study (the paper's definition).
        replay: its value of one replayed run (JSON: a bool, a float or None).
        short: its name in the tests' keys (`log_time`; default: `name`).
        count: a rate's key for its count of ones (default `<name>_count`; `successes`).
        variant: a labelled second definition (None: none).
        tune_variant: tuning optimises the variant (its scale does not depend on a trial's
            length), not the paper's definition.
        about: the paper's definition in one sentence, stated in the study's summary ("":
            none stated).
    """

    name: str
    label: str
    unit: str
    maximise: bool
    scale: Scale
    study: Callable[[Trials], NDArray[Any]]
    replay: Callable[[Trace], Any]
    short: str = ""
    count: str = ""
    variant: Variant | None = None
    tune_variant: bool = False
    about: str = ""

    def __post_init__(self) -> None:
        if not self.name.isidentifier():
            raise ConfigError(f"metric name {self.name!r}: not an identifier")
        if self.scale not in SCALES:
            raise ConfigError(
                f"metric {self.name}: scale {self.scale!r} is none of {', '.join(SCALES)}"
            )
        if self.tune_variant and self.variant is None:
            raise ConfigError(f"metric {self.name}: tune_variant without a variant")

    @property
    def heading(self) -> str:
        """The label with its unit, for a table's head ("time [s]")."""
        return f"{self.label} [{self.unit}]" if self.unit else self.label

    @property
    def test_key(self) -> str:
        """Its name in the tests between modes (`log_time`, `agreement`)."""
        short = self.short or self.name
        return f"log_{short}" if self.scale == "log" else short

    @property
    def count_key(self) -> str:
        """A rate's key for its count of ones in flat results (`successes`)."""
        return self.count or f"{self.name}_count"

    @property
    def summary_key(self) -> str:
        """Its key in a summary per mode (`success_rate` for a rate, else its name)."""
        return f"{self.name}_rate" if self.scale == "rate" else self.name

    def better(self, a: float, b: float) -> bool:
        """a is strictly better than b."""
        return a > b if self.maximise else a < b


def variant_key(m: Metric) -> str:
    """The key of a metric's variant beside the metric's own (`cosine_distance_per_action_mean`)."""
    assert m.variant is not None
    return f"{m.name}_{m.variant.suffix}"


def tuning_key(m: Metric) -> str:
    """The key of the value tuning optimises: the variant's with `tune_variant`, else the
    metric's."""
    return variant_key(m) if m.tune_variant else m.name


# --- the paper's metrics (Section IV-D) -----------------------------------------------------


def replay_products(trace: Trace) -> metrics.ActionProducts:
    """A replayed run's action products: its arbitrated ticks' actions in units of the
    velocity limits (what replay's action metrics are taken over)."""
    m = trace.arbitrated
    return metrics.ActionProducts.of(
        trace.step.U_human[m] / trace.v_max, trace.step.U_out[m] / trace.v_max
    )


def _replay_cosines(trace: Trace) -> metrics.CosineDistance:
    return metrics.summarise_cosines(metrics.cosine_distances(replay_products(trace)))


def _replay_cosine_sum(trace: Trace) -> float | None:
    cos = _replay_cosines(trace)
    return finite(cos.total) if int(cos.n_actions) > 0 else None


SUCCESS = Metric(
    "success",
    "success rate",
    "",
    maximise=True,
    scale="rate",
    study=lambda t: t.success,
    replay=lambda tr: tr.success,
    count="successes",
)
TIME = Metric(
    "time_s",
    "time",
    "s",
    maximise=False,
    scale="log",
    study=lambda t: t.time_s,
    replay=lambda tr: round(tr.time_s, 4),
    short="time",
)
COSINE_DISTANCE = Metric(
    "cosine_distance",
    "cosine distance",
    "",
    maximise=False,
    scale="linear",
    study=lambda t: t.cosine_sum,
    replay=_replay_cosine_sum,
    variant=Variant(
        "per_action_mean",
        "LABELLED VARIANT: per trajectory the mean per counted action (the sum divided by the "
        "actions), mean over trajectories; not the paper's definition",
        study=lambda t: t.cosine_mean,
        replay=lambda tr: finite(_replay_cosines(tr).mean),
    ),
    tune_variant=True,
    about=(
        "the paper's: per trajectory, the SUM over its actions of 1 - U_h.U_out / "
        "(|U_h||U_out|), idle actions (|U_h| or |U_out| <= 1e-9) skipped; over trajectories "
        "its geometric mean"
    ),
)
AGREEMENT = Metric(
    "agreement",
    "ratio of agreement",
    "",
    maximise=True,
    scale="linear",
    study=lambda t: t.agreement,
    replay=lambda tr: finite(metrics.agreement_of(replay_products(tr)).ratio),
)

_TABLE: dict[str, Metric] = {m.name: m for m in (SUCCESS, TIME, COSINE_DISTANCE, AGREEMENT)}
BUILT_IN: tuple[str, ...] = tuple(_TABLE)


def table() -> tuple[Metric, ...]:
    """Every metric, in the table's order (the paper's, then those registered)."""
    return tuple(_TABLE.values())


def names() -> tuple[str, ...]:
    return tuple(_TABLE)


#: Tuning's reports list the paper's metrics in this order: the constraint (success), the
#: default objective (agreement), the other action metric, the time.
_TUNING_ORDER: tuple[str, ...] = ("success", "agreement", "cosine_distance", "time_s")


def tuning_order() -> tuple[Metric, ...]:
    """Every metric in the order of tuning's results and reports (trials.csv's columns, a
    trial's and the held-out tables, the figures' rows): the paper's in `_TUNING_ORDER`, then
    those registered, in the table's order."""
    first = [_TABLE[n] for n in _TUNING_ORDER]
    return (*first, *(m for m in _TABLE.values() if m.name not in _TUNING_ORDER))


def metric(name: str) -> Metric:
    """The metric called `name`.

    Raises:
        ConfigError: there is none (one line naming those there are).
    """
    try:
        return _TABLE[name]
    except KeyError:
        raise ConfigError(f"unknown metric {name!r} (choose from {', '.join(_TABLE)})") from None


def register(m: Metric) -> Metric:
    """Add `m` to the table (after the others).

    Raises:
        ConfigError: a metric of that name is there already.
    """
    if m.name in _TABLE:
        raise ConfigError(f"metric {m.name!r} is in the table already")
    _TABLE[m.name] = m
    return m


def unregister(name: str) -> None:
    """Remove a registered metric (not one of the paper's)."""
    if name in BUILT_IN:
        raise ConfigError(f"metric {name!r} is one of the paper's: it stays")
    _TABLE.pop(name, None)
