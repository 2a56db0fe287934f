"""dsteleop.app."""
