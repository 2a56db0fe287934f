"""What `dsteleop tune` optimises, stated once, and how a trial's metrics score against it.

A trial evaluates one configuration on its sources, the tuned mode (`--mode`, DS by default)
and S paired:

    study      a fixed, seeded batch of the closed-loop study's trajectories (the same for
               every trial): metrics over trajectories
    sessions   headless replays of recorded sessions: metrics over sessions

Per source and mode the metrics are those of the metric table (app/study/metric_table.py,
docs/METHOD.md §7), summarised by their scale: `success` (the share of successful trials;
`successes` and `n` beside it), `time_s` (the geometric mean time [s]), `cosine_distance`
(on the study the mean cosine distance per action) and `agreement` (the mean ratio of
agreement); a metric registered in the table is one more.

The objective (the default: maximise DS's ratio of agreement; M is the tuned mode):

    value       the chosen metric of M; with both sources, the mean of the two sources'
                values (each weighs half)
    constraint  (unless turned off) M succeeds at least as often as S on the same paired
                trials, on every source: c = successes(S) - successes(M) <= 0
    best        the feasible complete trial with the best value (the lowest trial number
                among equal values)
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

from dsteleop.app.study import metric_table
from dsteleop.arbitration import Mode
from dsteleop.errors import ConfigError

Source = Literal["study", "sessions"]
ObjectiveKind = Literal["study", "sessions", "both"]

OBJECTIVES: tuple[str, ...] = ("study", "sessions", "both")


def key(source: str, mode: str, metric: str) -> str:
    """The flat name of one metric in a trial's results, e.g. `study.DS.agreement`."""
    return f"{source}.{mode}.{metric}"


@dataclass(frozen=True)
class Objective:
    """What a tuning study optimises.

    Attributes:
        kind: the sources, `study`, `sessions` or `both`.
        metric: the tuned mode's metric optimised (maximised or minimised by its nature).
        constrained: the tuned mode must succeed at least as often as S on every source.
        mode: the tuned mode's name (any registered mode but S, the reference).
    """

    kind: ObjectiveKind = "study"
    metric: str = "agreement"
    constrained: bool = True
    mode: str = "DS"

    def __post_init__(self) -> None:
        if self.kind not in OBJECTIVES:
            raise ConfigError(
                f"unknown objective {self.kind!r} (choose from {', '.join(OBJECTIVES)})"
            )
        metric_table.metric(self.metric)  # an unknown one: ConfigError naming the table's
        if Mode.parse(self.mode).value != self.mode:
            raise ConfigError(f"mode {self.mode!r}: write it {Mode.parse(self.mode).value!r}")
        if self.mode == Mode.S.value:
            raise ConfigError(
                "--mode S: S is the reference every trial is paired with; tune another mode"
            )

    @property
    def sources(self) -> tuple[Source, ...]:
        if self.kind == "both":
            return ("study", "sessions")
        return (self.kind,)

    @property
    def maximise(self) -> bool:
        return metric_table.metric(self.metric).maximise

    @property
    def direction(self) -> Literal["maximize", "minimize"]:
        """Optuna's name for the direction."""
        return "maximize" if self.maximise else "minimize"

    def statement(self) -> str:
        """The objective in one sentence (printed in every output)."""
        where = {
            "study": "the closed-loop study's tuning trajectories",
            "sessions": "the replayed sessions",
            "both": "the study's tuning trajectories and the replayed sessions (the mean of "
            "the two, each weighing half)",
        }[self.kind]
        verb = "maximise" if self.maximise else "minimise"
        text = f"{verb} {self.mode}'s {metric_table.metric(self.metric).heading} on {where}"
        if self.constrained:
            text += (
                f", subject to {self.mode} succeeding at least as often as S on the same paired "
                "trials" + (" (on each source)" if self.kind == "both" else "")
            )
        return text

    def value(self, metrics: Mapping[str, float]) -> float:
        """The objective's value of one trial's metrics."""
        vals = [float(metrics[key(s, self.mode, self.metric)]) for s in self.sources]
        return sum(vals) / len(vals)

    def constraints(self, metrics: Mapping[str, float]) -> list[float]:
        """Per source, successes(S) - successes(mode): feasible when every one is <= 0
        (an empty list when unconstrained)."""
        if not self.constrained:
            return []
        return [
            float(metrics[key(s, "S", "successes")])
            - float(metrics[key(s, self.mode, "successes")])
            for s in self.sources
        ]

    def feasible(self, metrics: Mapping[str, float]) -> bool:
        return all(c <= 0 for c in self.constraints(metrics))

    def better(self, a: float, b: float) -> bool:
        """a is strictly better than b."""
        return a > b if self.maximise else a < b

    def to_dict(self) -> dict[str, object]:
        return {
            "kind": self.kind,
            "metric": self.metric,
            "constrained": self.constrained,
            "mode": self.mode,
            "direction": self.direction,
            "statement": self.statement(),
        }
