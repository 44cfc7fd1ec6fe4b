"""icefloe: the software stack of a small education robot."""
