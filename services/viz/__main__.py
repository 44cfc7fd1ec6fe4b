"""``python -m icefloe.services.viz`` (or ``icefloe viz``): a live Rerun view of a robot, from a laptop.

The options, and how the view starts, are `command.py`'s (shared with the ``icefloe viz`` verb);
the view itself is `app.py`'s.
"""

from .command import cli

if __name__ == "__main__":
    cli()
