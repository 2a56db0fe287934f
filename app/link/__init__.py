"""The robot link over Zenoh (docs/link.md)."""
