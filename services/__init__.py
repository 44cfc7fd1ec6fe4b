"""One folder per icefloe process."""
