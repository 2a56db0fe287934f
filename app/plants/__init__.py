"""The `ports.Plant`s: the PyBullet kitchen (`kitchen`) and a recorded robot (`recorded`)."""
