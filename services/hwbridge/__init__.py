"""hwbridge: the bridge between the bus and the I/O board, with a hard real-time cycle.

Two processes: the bus side (``__main__.py`` + ``bridge.py``: a normal icefloe
service) and the real-time cycle (``rt.py``), joined by shared memory
(``shm.py``). Pure logic in ``control.py``; board backends in
``penguinpi.py`` and ``icoboard.py``. See docs/hwbridge.md.
"""
