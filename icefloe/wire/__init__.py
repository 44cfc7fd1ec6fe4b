"""Board wire protocols, shared by hwbridge (the host side) and the simulator (the board side)."""
