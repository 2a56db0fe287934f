"""Sessions as LeRobot v3.0 datasets: export, live recording, reading back (docs/datasets.md)."""
