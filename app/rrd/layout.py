"""Entity paths and timelines of dsteleop's Rerun recordings: the one place that names them.

One recording per episode of a session (recording id = the episode's name, `SESSION/epN`,
or a replayed video's; application id `dsteleop`). Each run of it (a replayed mode, or the
live loop) logs under its own root, so the modes sit side by side on one timeline and
"alpha/yaw" of S plots against DS:

    {root}/alpha/{dim}, {root}/P_human/{dim}, ... (STEP_ARRAYS)   Scalars, one row per tick
                                                                  (NaN where the arbitration
                                                                  did not run)
    {root}/palm                  Transform3D: the robot's palm (X_current, base frame)
    {root}/hand                  Transform3D: the mapped hand (X_human), when fresh
    {root}/goal                  Transform3D: the goal the robot knows (noisy; the MAP
                                 candidate's, for a robot that infers its goal)
    {root}/belief/{candidate}    Scalars: a robot not told its goal: its belief in each
                                 candidate after each tick (NaN where not a candidate then)
    {root}/confidence/{dim}      Scalars: its confidence per dimension (`joint`: in the whole
                                 goal), NaN where it was told
    {root}/scene/{frame}         Transform3D per tick: the scene's links and bodies, with their
                                 shapes (from the same `SceneGeometry` the browser draws) below
    {root}/events                TextLog: task events (goal, grasp, release, outcome), notes
    {root}/status                TextLog: lost-hand intervals (lost with its reason, tracking)
    goal_true/pick, goal_true/place   Transform3D, static: the true goals
    camera/image                 EncodedImage (JPEG): the camera frames, when there are any
    camera/landmarks             Points2D: the tracked landmarks over them [px]

Root: the mode's name for a replay ("S", "DS", "manual", "autonomous"); "live" for a
running loop (whose mode may change: the change is an event).
"""

from __future__ import annotations

APPLICATION_ID = "dsteleop"
#: The timeline every entity is logged on: loop time since the run's first tick [s].
TIMELINE = "tick_time"
LIVE_ROOT = "live"

CAMERA_IMAGE = "camera/image"
CAMERA_LANDMARKS = "camera/landmarks"


def series(root: str, quantity: str, dim: str) -> str:
    """A per-dimension time series, e.g. series("DS", "alpha", "yaw") = "DS/alpha/yaw"."""
    return f"{root}/{quantity}/{dim}"


def palm(root: str) -> str:
    return f"{root}/palm"


def hand(root: str) -> str:
    return f"{root}/hand"


def goal(root: str) -> str:
    return f"{root}/goal"


def belief(root: str, candidate: str) -> str:
    """The belief in one goal candidate, e.g. belief("DSC", "ladle") = "DSC/belief/ladle"."""
    return f"{root}/belief/{candidate}"


def confidence(root: str, dim: str) -> str:
    """The confidence in one dimension of the goal ("joint": in all at once)."""
    return f"{root}/confidence/{dim}"


def goal_true(name: str) -> str:
    return f"goal_true/{name}"


def scene_frame(root: str, frame: str) -> str:
    """A scene frame ("robot/palm", "spoon", ...) under a run's root."""
    return f"{root}/scene/{frame}"


def events(root: str) -> str:
    return f"{root}/events"


def status(root: str) -> str:
    return f"{root}/status"
