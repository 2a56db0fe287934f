"""The control loop: its settings, the pure tick, the runner that owns the clock, the
operator's request mailbox and the one-slot broadcast of tick records."""

from dsteleop.app.loop.config import LoopConfig, LostPolicy
from dsteleop.app.loop.runner import TeleopLoop

__all__ = ["LoopConfig", "LostPolicy", "TeleopLoop"]
