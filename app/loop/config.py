"""The loop's settings, recorded with every session."""

from __future__ import annotations

import dataclasses
import enum
import math
from dataclasses import dataclass, field
from typing import Any

from dsteleop.arbitration import ArbitrationConfig, Mode
from dsteleop.errors import ConfigError


class LostPolicy(str, enum.Enum):
    """What the robot does while the hand is lost."""

    HALT = "halt"
    ASSIST = "assist"


@dataclass(frozen=True)
class LoopConfig:
    """Loop settings (validated at construction).

    Attributes:
        rate_hz: control rate [Hz].
        mode: arbitration mode at start.
        stale_limit_s: hand input older than this is stale [s].
        halt_ramp_s: the halt ramp brings the commanded speed to 0 in this time [s].
        lost_policy: `halt` (default) or `assist`.
        assist_speed: fraction of the policy's speed used while assisting, (0, 1].
        assist_goal_tolerance_m: assisting stops this close to the goal [m].
        input_delay_s: injected delay on the human input [s] (the paper's study used one).
        reset_after_s: after an outcome, the loop resets the task (the next trial) this long
            after it [s]; 0: never (the operator resets).
        arbitration: the arbitration hyper-parameters (with eq (2)'s reference bound).
    """

    rate_hz: float = 30.0
    mode: Mode = Mode.DS
    stale_limit_s: float = 0.1
    halt_ramp_s: float = 0.066
    lost_policy: LostPolicy = LostPolicy.HALT
    assist_speed: float = 0.5
    assist_goal_tolerance_m: float = 0.01
    input_delay_s: float = 0.0
    reset_after_s: float = 0.0
    arbitration: ArbitrationConfig = field(default_factory=ArbitrationConfig)

    def __post_init__(self) -> None:
        for name in (
            "rate_hz",
            "stale_limit_s",
            "halt_ramp_s",
            "assist_speed",
            "assist_goal_tolerance_m",
        ):
            v = getattr(self, name)
            if isinstance(v, bool) or not (
                isinstance(v, (int, float)) and math.isfinite(v) and v > 0
            ):
                raise ConfigError(f"{name} must be a positive number, got {v!r}")
        for name in ("input_delay_s", "reset_after_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (
                isinstance(v, (int, float)) and math.isfinite(v) and v >= 0
            ):
                raise ConfigError(f"{name} must be a number >= 0, got {v!r}")
        if self.assist_speed > 1:
            raise ConfigError(f"assist_speed must be in (0, 1], got {self.assist_speed!r}")

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    def replace(self, **changes: Any) -> LoopConfig:
        return dataclasses.replace(self, **changes)

    def to_dict(self) -> dict[str, Any]:
        d = dataclasses.asdict(self)
        d["mode"] = self.mode.value
        d["lost_policy"] = self.lost_policy.value
        d["arbitration"] = self.arbitration.to_dict()
        return d

    @classmethod
    def from_dict(
        cls, d: dict[str, Any], arbitration: ArbitrationConfig | None = None
    ) -> LoopConfig:
        """The config a session recorded (missing fields take their defaults); with
        `arbitration` (already parsed), `d` holds the loop's own fields only.

        Sessions of schema 1 kept eq (2)'s reference bound (`max_lead_m`, `max_lead_rad`)
        here; it now belongs to the arbitration and is moved there (a parsed `arbitration`
        keeps its own).

        Raises:
            ConfigError: an unknown field or a value out of its domain.
        """
        d = dict(d)
        arb = dict(d.pop("arbitration", {})) if arbitration is None else {}
        for moved in ("max_lead_m", "max_lead_rad"):
            if moved in d:
                arb.setdefault(moved, d.pop(moved))
        names = {f.name for f in dataclasses.fields(cls)} - {"arbitration"}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ConfigError(f"unknown loop setting(s): {', '.join(unknown)}")
        if "mode" in d:
            d["mode"] = Mode.parse(str(d["mode"]))
        if "lost_policy" in d:
            try:
                d["lost_policy"] = LostPolicy(d["lost_policy"])
            except ValueError:
                raise ConfigError(f"unknown lost_policy {d['lost_policy']!r}") from None
        if arbitration is None:
            arbitration = ArbitrationConfig.from_dict(arb)
        return cls(**d, arbitration=arbitration)
