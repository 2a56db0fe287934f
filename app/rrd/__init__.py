"""Rerun recordings of sessions, replays and live runs (docs/recordings.md).

`layout` names every entity once; `log` turns tick records into Rerun columns; `live` logs a
running loop from its own thread; `files` writes and merges `.rrd` files. Only this package
imports `rerun` (never arbitration, tracking or robot).
"""
