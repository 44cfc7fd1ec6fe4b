"""The simulator process: the world, a board model, the GPIO lines, and their handles on the bus.

``python -m icefloe.services.sim --config X`` (see ``docs/sim.md``).
"""
