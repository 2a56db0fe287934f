"""The search space of `dsteleop tune`: which arbitration hyper-parameters vary, over what.

One `--space NAME=SPEC` per parameter; NAME is any field of `ArbitrationConfig`, or a mode's
own parameter written `<mode>.<field>` (`scalar.cap`):

    NAME=LOW:HIGH          uniform on [LOW, HIGH] (integers only, for an integer field)
    NAME=log:LOW:HIGH      log-uniform on [LOW, HIGH], 0 < LOW
    NAME=int:LOW:HIGH      integers LOW..HIGH
    NAME=intlog:LOW:HIGH   integers LOW..HIGH, log-uniform (1 <= LOW)
    NAME=V1,V2,...         these values only (a categorical choice)

Without `--space`, the tuned mode's own default space, stated next to the mode
(`arbitration/modes/<mode>.py`, `ModeSpec.space`): for DS the paper's own list of
hyper-parameters to tune (its limitation 1, eq (5) and (7) and the temporal window) over
ranges about their defaults (`DEFAULT_SPACE`) and its two caps (translation, rotation) over
the scalar's cap range, for the scalar baseline its cap and scale.

Grid search (`--sampler grid`) needs finite values: a choice keeps its values, an integer
range all its integers up to `points` of them, a range `points` values evenly spaced (log
ranges geometrically), both ends included.

A value can lie outside the field's domain (`p=0.8,4`: p must be > 1): the space is still
accepted, `out_of_domain` names such values, and a trial that draws one fails and is
recorded as failed (the study goes on).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np

from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import ConfigError

Kind = Literal["float", "log", "int", "intlog", "choice"]
Value = float | int

#: DS's default `--space`: eq (5)'s kappa, eq (7)'s p, q, b and the window (docs/METHOD.md
#: §6), each over about one order of magnitude around its default (`arbitration/modes/ds.py`).
DEFAULT_SPACE: tuple[str, ...] = Mode.DS.spec.space


def default_space(mode: str) -> tuple[str, ...]:
    """The default `--space` of `mode` (its plug-in's); a ConfigError if it has none."""
    m = Mode.parse(mode)
    if not m.spec.space:
        raise ConfigError(
            f"--mode {m.value} has no parameters of its own to tune; give --space NAME=SPEC"
        )
    return m.spec.space


SPACE_GRAMMAR = (
    "NAME=LOW:HIGH, NAME=log:LOW:HIGH, NAME=int:LOW:HIGH, NAME=intlog:LOW:HIGH or "
    "NAME=V1,V2,... (NAME: a field of the arbitration configuration or a mode's own "
    "parameter, MODE.FIELD)"
)


@dataclass(frozen=True)
class Dimension:
    """One searched hyper-parameter.

    Attributes:
        name: the `ArbitrationConfig` field.
        kind: float, log, int, intlog (ranges) or choice (listed values).
        low: the range's low end (ranges; the field's unit).
        high: the range's high end (ranges).
        choices: the listed values (choice).
        spec: the text it was given as (`NAME=...`).
    """

    name: str
    kind: Kind
    low: float = 0.0
    high: float = 0.0
    choices: tuple[Value, ...] = ()
    spec: str = ""

    @property
    def integer(self) -> bool:
        return self.kind in ("int", "intlog") or (
            self.kind == "choice" and all(isinstance(v, int) for v in self.choices)
        )

    @property
    def log(self) -> bool:
        return self.kind in ("log", "intlog")

    def grid(self, points: int) -> tuple[Value, ...]:
        """The values of a grid search (module docstring)."""
        if self.kind == "choice":
            return self.choices
        if self.kind in ("int", "intlog"):
            lo, hi = int(self.low), int(self.high)
            if hi - lo + 1 <= points:
                return tuple(range(lo, hi + 1))
            xs = np.geomspace(lo, hi, points) if self.log else np.linspace(lo, hi, points)
            return tuple(sorted({round(float(x)) for x in xs}))
        xs = (
            np.geomspace(self.low, self.high, points)
            if self.log
            else np.linspace(self.low, self.high, points)
        )
        return tuple(float(f"{float(x):.6g}") for x in xs)


def field_kinds() -> Mapping[str, bool]:
    """Every numeric ArbitrationConfig field (a word, `human_reference`, is not searched) ->
    whether it is an integer."""
    words = ArbitrationConfig.word_fields()
    return {
        k: isinstance(v, int) for k, v in ArbitrationConfig().to_dict().items() if k not in words
    }


def parse_dimension(item: str) -> Dimension:
    """One `NAME=SPEC` (module docstring); a ConfigError names what is wrong."""
    name, sep, spec = item.partition("=")
    name, spec = name.strip(), spec.strip()
    fields = field_kinds()
    if not sep or not name or not spec:
        raise ConfigError(f"--space needs NAME=SPEC ({SPACE_GRAMMAR}), got {item!r}")
    if name not in fields:
        raise ConfigError(
            f"--space {item}: unknown parameter {name!r} (choose from {', '.join(sorted(fields))})"
        )
    integer_field = fields[name]

    def number(text: str) -> float:
        try:
            v = float(text)
        except ValueError:
            raise ConfigError(f"--space {item}: not a number: {text!r}") from None
        if not math.isfinite(v):
            raise ConfigError(f"--space {item}: not a finite number: {text!r}")
        return v

    if "," in spec:
        values = [number(t.strip()) for t in spec.split(",") if t.strip()]
        if len(values) < 2 or len(set(values)) != len(values):
            raise ConfigError(f"--space {item}: a choice needs two or more different values")
        if integer_field:
            if any(v != int(v) for v in values):
                raise ConfigError(f"--space {item}: {name} is an integer")
            return Dimension(name, "choice", choices=tuple(int(v) for v in values), spec=item)
        return Dimension(name, "choice", choices=tuple(values), spec=item)
    parts = spec.split(":")
    kind: Kind
    if len(parts) == 2:
        kind = "int" if integer_field else "float"
        lo_s, hi_s = parts
    elif len(parts) == 3 and parts[0] in ("log", "int", "intlog"):
        kind = parts[0]  # type: ignore[assignment]
        lo_s, hi_s = parts[1:]
    else:
        raise ConfigError(f"--space {item}: malformed range ({SPACE_GRAMMAR})")
    lo, hi = number(lo_s), number(hi_s)
    if not lo < hi:
        raise ConfigError(f"--space {item}: the range needs LOW < HIGH, got {lo_s}:{hi_s}")
    if kind == "log" and integer_field:
        kind = "intlog"
    if kind == "float" and integer_field:
        kind = "int"
    if kind in ("int", "intlog") and (lo != int(lo) or hi != int(hi)):
        raise ConfigError(f"--space {item}: an integer range needs integer ends")
    if kind == "log" and lo <= 0:
        raise ConfigError(f"--space {item}: a log range needs LOW > 0")
    if kind == "intlog" and lo < 1:
        raise ConfigError(f"--space {item}: an integer log range needs LOW >= 1")
    return Dimension(name, kind, low=lo, high=hi, spec=item)


def parse_space(items: Sequence[str], mode: str = "DS") -> tuple[Dimension, ...]:
    """The dimensions of `--space` items (the tuned mode's defaults when there are none)."""
    dims = tuple(parse_dimension(s) for s in (items or default_space(mode)))
    names = [d.name for d in dims]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise ConfigError(f"--space names {', '.join(twice)} more than once")
    return dims


def out_of_domain(dims: Sequence[Dimension], base: ArbitrationConfig) -> list[str]:
    """One sentence per value at the edge of a dimension (its ends or choices) that the
    configuration rejects: the trials that draw it will fail."""
    out = []
    for d in dims:
        edges = d.choices if d.kind == "choice" else (d.low, d.high)
        for v in edges:
            value: Value = int(v) if d.integer else float(v)
            try:
                base.replace(**{d.name: value})
            except ConfigError as exc:
                out.append(f"{d.name}={value:g}: {exc}")
    return out


def as_values(params: Mapping[str, Any], dims: Sequence[Dimension]) -> dict[str, Value]:
    """Sampled parameters with each dimension's type (ints for integer dimensions)."""
    out: dict[str, Value] = {}
    for d in dims:
        v = params[d.name]
        out[d.name] = int(v) if d.integer else float(v)
    return out
