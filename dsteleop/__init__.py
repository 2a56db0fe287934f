"""dsteleop: telemanipulation with dimension-specific shared autonomy."""

__version__ = "0.1.0"
