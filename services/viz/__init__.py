"""viz: a live Rerun view of robots on the bus (see docs/viz.md and ``app.py``)."""
