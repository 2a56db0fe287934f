"""The browser view: a Viser server fed by the loop's tick records (`server`), its 2-D panel
(`panel`: gauges, status, plot, camera) and its 3-D scene (`scene`). A sink: it never
touches the loop's state and never imports PyBullet."""
