"""Headless replay of sessions and videos (`core`, `video`), and their plots (`plots`)."""
