"""The files icefloe ships: robot configs (``robots/``), worlds (``worlds/``), the Zenoh
access-control template (``zenoh/``) and systemd unit templates (``systemd/``).

This folder installs as the package ``icefloe.share`` so that a wheel carries these files;
code finds them with `icefloe.paths` (by name, with the user's own folders first), never
relative to the source tree. The shell scripts beside them are for a checkout.
"""
