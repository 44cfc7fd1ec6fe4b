"""The simulated camera's texture cache (sim/camera.py `TextureCache`): bounded in bytes, the most
recently used kept, so the camera service, where the simulated camera renders, does not grow as a
robot drives round and sees its markers at ever more sizes (bench/stack_memory.py)."""

from __future__ import annotations

import numpy as np

from icefloe.sim.camera import TextureCache


def test_the_cache_keeps_the_most_recently_used_within_its_limit() -> None:
    cache = TextureCache(limit=3 * 100)
    for size in range(10):
        cache.put((1, size), np.zeros(100, np.uint8))
        assert cache.get((1, 0)) is not None   # used after every put: never the least recently used
    kept = [size for size in range(10) if cache.get((1, size)) is not None]
    assert len(kept) == 3 and 0 in kept and 9 in kept


def test_one_texture_larger_than_the_limit_is_still_kept_until_the_next() -> None:
    cache = TextureCache(limit=10)
    cache.put((1, 50), np.zeros(1000, np.uint8))
    assert cache.get((1, 50)) is not None
    cache.put((1, 51), np.zeros(1000, np.uint8))
    assert cache.get((1, 50)) is None and cache.get((1, 51)) is not None
