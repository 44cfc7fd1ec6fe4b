"""The simulated robot: world physics and wire-faithful board models."""
