"""`--source demo`: the built-in demo, a simulated person doing the task through the
tracking pipeline (`inputs.demo.DemoOperator`, its hand rendered as landmarks by
`inputs.demo.demo_source`); it watches the robot (an observer of every tick). Its operator
world sets the task's goal noise and the link's delay unless the command line does."""

from __future__ import annotations

from typing import Any

from dsteleop.app.inputs.demo import DemoCamera, DemoConfig, DemoOperator, demo_source
from dsteleop.app.sources import Defaults, Opened, SourceContext, SourceKind
from dsteleop.tracking.sources import SourceSpec


def open_demo(spec: SourceSpec, ctx: SourceContext) -> Opened:
    change_to, change_at_s = ctx.change_mind or (None, DemoConfig.change_at_s)
    config = DemoConfig(seed=ctx.seed, change_to=change_to, change_at_s=change_at_s)
    demo = DemoOperator(ctx.task.true_goals, ctx.X_start, config, arbitration=ctx.arbitration)
    frames = demo_source(
        demo, DemoCamera(ctx.X_start, ctx.mapping), realtime=ctx.realtime, seed=ctx.seed
    )
    return Opened(frames=frames, observers=(demo,))


def defaults(seed: int) -> Defaults:
    """The operator world's goal noise and link delay (docs/operator.md)."""
    world = DemoConfig(seed=seed).world
    return Defaults(goal_noise_m=world.goal_sigma_m, input_delay_s=world.delay_s)


def info() -> dict[str, Any]:
    return {"world": DemoConfig().describe()}


KIND = SourceKind(
    "demo", "demo", open_demo, label=lambda spec: "demo", defaults=defaults, info=info
)
