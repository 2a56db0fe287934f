"""dsteleop.tracking."""
