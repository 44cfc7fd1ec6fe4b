"""The lap judge (RVSS "Need 4 Speed" scoring of a track world)."""
