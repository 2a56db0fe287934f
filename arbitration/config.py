"""All arbitration hyper-parameters in one frozen, validated, JSON-round-trippable object.

Defaults (and why):
    kappa = 4.0       von Mises concentration of eq (5): P(R) falls to 0.5 at ~34 deg off the
                      goal and to ~0.02 at 90 deg.
    p, q = 4.0, 6.0   beta-prime shapes of eq (7): B peaks at 0.54 * b * |psi_robot| and falls
                      to ~0.25 at 3x and ~0.1 at 4x that.
    b = 1.0           |psi_human| whose density mean sits at b * |psi_robot|.
    window = 5        moving-average window (ticks) on alpha_i and B_i (paper limitation 2).
    gains             K_r of the goal-seeking policy U_robot = sat(K_r * diff(goal, current)).
    limits            velocity saturation: translation by norm [m/s], rotation by norm [rad/s],
                      each finger alone [1/s].
    alloc_floor_*     eq (3)/(4)'s denominator floor: where |goal_i - start_i| is tiny (a
                      dimension the task does not move), P stays a smooth function of the
                      distance on the task's own scale, 2 cm (about the success tolerances,
                      1-3 cm) and 0.1 of openness, instead of a step at a millimetre.
    still_*           eq (6)'s unit directions are 0 below these: u(cur, prev), a one-tick
                      difference, is gated by a speed (5 mm/s, 0.05 rad/s, 0.05 openness/s)
                      and u(cur, start) by a distance (5 mm, 0.05 rad, 0.02): the scale of a
                      hand's drift and tremor while it holds still (docs/METHOD.md §4 says how
                      they were chosen and what a camera's noise floor does to them).
    psi_robot_floor   the |psi_robot| ~ 0 rule of eq (7): the beta-prime reference is
                      max(|psi_robot|, psi_robot_floor) (0.25: a quarter of a unit direction,
                      the scale of psi), so B stays finite, and an operator who is not changing
                      speed while the robot is not either gets B ~ 0 (control goes to them).
    mode_params       each mode's own parameters (`arbitration/modes/`), by mode name; written
                      `<mode>.<field>` in the flat form (`to_dict`, `--param scalar.cap=0.5`);
                      a mode's shorthand sets several (`--param DS.cap=0.5`: DS's three caps).
    belief            the belief over candidate goals (`belief.BeliefParams`: beta, epsilon,
                      the tolerances that scale each dimension; docs/METHOD.md §10), written
                      `belief.<field>` in the flat form (`--param belief.beta=2`); read by
                      whoever keeps a belief (the loop with `--goal infer`), not by eq (1)-(8).
    human_reference   what eq (4)-(6) read as X_human (docs/METHOD.md §2): "hand", the hand's
                      mapped pose (the paper's reading; under the rate mapping the integral of
                      the hand's motion, which drifts without bound from a robot that resists
                      it), or "leaky", the hand's reference whose lead over the robot decays
                      (`arbiters.leaky_reference`), bounded by about v_max * human_leak_s.
    human_leak_s      the leaky reference's time constant, 1.0 s: about one submovement of a
                      reach (0.3-0.5 s) plus the dwell after it, so a lead the person keeps
                      pushing for survives a movement, and one they stopped pushing for fades
                      within about a second (their intent is then where the robot is).
    max_lead_m/_rad   eq (2) integrates the commanded reference, which may lead the achieved
                      palm by at most 3 cm / 0.25 rad (`policy.advance_reference`): a robot
                      that lags its position controller keeps the hand's full motion, and one
                      blocked by the table does not wind the reference up.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import NDArray

from dsteleop.arbitration import modes
from dsteleop.arbitration.belief import NAME as BELIEF
from dsteleop.arbitration.belief import BeliefParams
from dsteleop.errors import ConfigError

#: Fields of earlier versions, read from old sessions and dropped: eq (4)'s floor and eq (6)'s
#: direction threshold were one `eps`, 1e-3 (docs/METHOD.md says why they are apart now).
RETIRED = frozenset({"eps_trans_m", "eps_rot_rad", "eps_finger"})

#: A hyper-parameter out of its domain (the project's `ConfigError`; the message names it).
InvalidConfig = ConfigError

#: What eq (4)-(6) may read as X_human (`ArbitrationConfig.human_reference`).
HumanReference = Literal["hand", "leaky"]
HUMAN_REFERENCES: tuple[str, ...] = ("hand", "leaky")

#: The fields that are words, not numbers.
_WORDS = frozenset({"human_reference"})
#: The fields that hold a group of parameters, written `<group>.<field>` in the flat form.
_GROUPS = frozenset({"mode_params", "belief"})


@dataclass(frozen=True)
class ArbitrationConfig:
    """Hyper-parameters of the arbitration (see module docstring for the defaults)."""

    kappa: float = 4.0
    p: float = 4.0
    q: float = 6.0
    b: float = 1.0
    window: int = 5
    k_trans_per_s: float = 2.0
    k_rot_per_s: float = 2.0
    k_finger_per_s: float = 2.0
    v_max_mps: float = 0.25
    w_max_radps: float = 1.0
    g_max_per_s: float = 4.0
    alloc_floor_m: float = 0.02
    alloc_floor_openness: float = 0.1
    still_speed_mps: float = 0.005
    still_rate_radps: float = 0.05
    still_openness_per_s: float = 0.05
    still_distance_m: float = 0.005
    still_angle_rad: float = 0.05
    still_openness: float = 0.02
    psi_robot_floor: float = 0.25
    max_lead_m: float = 0.03
    max_lead_rad: float = 0.25
    human_reference: HumanReference = "hand"
    human_leak_s: float = 1.0
    #: (mode name, its parameters) of every mode with parameters of its own.
    mode_params: tuple[tuple[str, Any], ...] = field(default_factory=modes.default_params)
    #: The belief over candidate goals (`belief.<field>` in the flat form).
    belief: BeliefParams = field(default_factory=BeliefParams)

    def __post_init__(self) -> None:
        if not isinstance(self.belief, BeliefParams):
            raise InvalidConfig(f"belief must be BeliefParams, got {self.belief!r}")
        for f in dataclasses.fields(self):
            if f.name in _GROUPS or f.name in _WORDS:
                continue
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise InvalidConfig(f"{f.name} must be a number, got {value!r}")
            if not math.isfinite(value) or value <= 0:
                raise InvalidConfig(f"{f.name} must be finite and > 0, got {value!r}")
        if self.p <= 1.0:
            raise InvalidConfig(f"p must be > 1 (beta prime needs a mode), got {self.p!r}")
        if self.q <= 1.0:
            raise InvalidConfig(f"q must be > 1 (beta prime needs a mean), got {self.q!r}")
        if not isinstance(self.window, int):
            raise InvalidConfig(f"window must be an integer >= 1, got {self.window!r}")
        if self.human_reference not in HUMAN_REFERENCES:
            raise InvalidConfig(
                f"human_reference must be one of {', '.join(HUMAN_REFERENCES)}, "
                f"got {self.human_reference!r}"
            )

    def replace(self, **changes: Any) -> ArbitrationConfig:
        """A copy with some fields changed (validated; an unknown name is a ConfigError)."""
        return ArbitrationConfig.from_dict({**self.to_dict(), **_expand_shorthands(changes)})

    def params_of(self, mode: str) -> Any:
        """The own parameters of `mode` (None for a mode without any)."""
        for name, params in self.mode_params:
            if name == mode:
                return params
        cls = modes.Mode.parse(mode).spec.params
        return None if cls is None else cls()

    def to_dict(self) -> dict[str, Any]:
        """Every field by name, the modes' own parameters as `<mode>.<field>`, the belief's
        as `belief.<field>`."""
        out = {f: getattr(self, f) for f in self.field_names()}
        for name, params in self.mode_params:
            for k, v in dataclasses.asdict(params).items():
                out[f"{name}.{k}"] = v
        for k, v in dataclasses.asdict(self.belief).items():
            out[f"{BELIEF}.{k}"] = v
        return out

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> ArbitrationConfig:
        """From `to_dict`'s form; a missing mode or belief parameter takes its default (a
        session recorded before the belief had parameters reads the defaults)."""
        names = set(cls.field_names())
        data = _expand_shorthands({k: v for k, v in data.items() if k not in RETIRED})
        belief = _belief_of(data)
        own: dict[str, dict[str, Any]] = {}
        for k in [k for k in data if "." in k]:
            mode, _, name = k.partition(".")
            own.setdefault(mode, {})[name] = data.pop(k)
        unknown = sorted(set(data) - names)
        if unknown:
            known = ", ".join(sorted(names))
            raise InvalidConfig(
                f"unknown arbitration parameter(s): {', '.join(unknown)} (known: {known})"
            )
        params = dict(modes.default_params())
        for mode, given in own.items():
            if mode not in params:
                modes.params_class(mode)  # an unknown mode raises
                raise InvalidConfig(
                    f"mode {mode} has no parameters (got {mode}.{next(iter(given))})"
                )
            fields = {f.name for f in dataclasses.fields(params[mode])}
            bad = sorted(set(given) - fields)
            if bad:
                raise InvalidConfig(
                    f"unknown parameter {mode}.{bad[0]} (known: "
                    f"{', '.join(f'{mode}.{f}' for f in sorted(fields))})"
                )
            params[mode] = dataclasses.replace(params[mode], **given)
        return cls(**data, mode_params=tuple(params.items()), belief=belief)

    @classmethod
    def word_fields(cls) -> frozenset[str]:
        """The shared parameters whose values are words (`human_reference`), not numbers."""
        return _WORDS

    @classmethod
    def field_names(cls) -> tuple[str, ...]:
        """The shared parameters (the modes' own are in `mode_params`, the belief's in
        `belief`)."""
        return tuple(f.name for f in dataclasses.fields(cls) if f.name not in _GROUPS)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), sort_keys=True)

    @classmethod
    def from_json(cls, text: str) -> ArbitrationConfig:
        data = json.loads(text)
        if not isinstance(data, dict):
            raise InvalidConfig("arbitration config JSON must be an object")
        return cls.from_dict(data)

    # Per-dimension vectors, for D = 6 + n_fingers dimensions.
    def gains(self, n_fingers: int) -> NDArray[np.float64]:
        return _per_dim(self.k_trans_per_s, self.k_rot_per_s, self.k_finger_per_s, n_fingers)

    def v_max(self, n_fingers: int) -> NDArray[np.float64]:
        return _per_dim(self.v_max_mps, self.w_max_radps, self.g_max_per_s, n_fingers)

    def alloc_floor(self, n_fingers: int) -> NDArray[np.float64]:
        """Eq (3)/(4)'s denominator floors (the rotation entries are not used)."""
        return _per_dim(self.alloc_floor_m, math.pi, self.alloc_floor_openness, n_fingers)

    def still_step(self, n_fingers: int, dt: float) -> NDArray[np.float64]:
        """Eq (6): the smallest one-tick difference (over dt [s]) that has a direction."""
        speeds = (self.still_speed_mps, self.still_rate_radps, self.still_openness_per_s)
        return _per_dim(*(v * dt for v in speeds), n_fingers)

    def still_offset(self, n_fingers: int) -> NDArray[np.float64]:
        """Eq (6): the smallest difference from the start that has a direction."""
        return _per_dim(self.still_distance_m, self.still_angle_rad, self.still_openness, n_fingers)


def _belief_of(data: dict[str, Any]) -> BeliefParams:
    """The belief's parameters, taken out of the flat form `data` (`belief.<field>`; the
    others keep their defaults); an unknown field is a ConfigError listing the known."""
    prefix = f"{BELIEF}."
    given = {k[len(prefix) :]: data.pop(k) for k in [k for k in data if k.startswith(prefix)]}
    fields = {f.name for f in dataclasses.fields(BeliefParams)}
    bad = sorted(set(given) - fields)
    if bad:
        raise InvalidConfig(
            f"unknown parameter {prefix}{bad[0]} (known: "
            f"{', '.join(prefix + f for f in sorted(fields))})"
        )
    return BeliefParams(**given)


def _expand_shorthands(data: dict[str, Any]) -> dict[str, Any]:
    """The flat form with the modes' shorthands (`ModeSpec.shorthands`, `DS.cap`) replaced
    by the parameters they set; a parameter given by its own name wins."""
    out = dict(data)
    for spec in (m.spec for m in modes.registered()):
        for short, names in spec.shorthands:
            key = f"{spec.name}.{short}"
            if key in out:
                value = out.pop(key)
                for name in names:
                    out.setdefault(f"{spec.name}.{name}", value)
    return out


@functools.lru_cache(maxsize=256)
def _per_dim(trans: float, rot: float, finger: float, n_fingers: int) -> NDArray[np.float64]:
    """[trans] * 3 + [rot] * 3 + [finger] * F, read-only (cached: asked for every tick)."""
    v = np.concatenate([np.full(3, trans), np.full(3, rot), np.full(n_fingers, finger)])
    v.flags.writeable = False
    return v
