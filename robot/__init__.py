"""dsteleop.robot."""
