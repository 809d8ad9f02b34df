import numpy as np

from renderer.cache import PEMCache, cache_key
from renderer.lighting.filters import Filter
from renderer.lighting.pem import PEMSettings

from conftest import sun_sky_cube


def _cube(seed):
    return sun_sky_cube(16, (np.cos(seed), 1.0, np.sin(seed)), sun_radiance=100.0 + seed)


def test_key_changes_with_every_parameter():
    base = cache_key("abc", 16, PEMSettings(24))
    assert base == cache_key("abc", 16, PEMSettings(24))
    others = [cache_key("abd", 16, PEMSettings(24)), cache_key("abc", 32, PEMSettings(24)),
              cache_key("abc", 16, PEMSettings(48)), cache_key("abc", 16, PEMSettings(24, Filter.BOX)),
              cache_key("abc", 16, PEMSettings(24, levels=3)), cache_key("abc", 16, PEMSettings(24, base_level=1)),
              cache_key("abc", 16, PEMSettings(24, whole_sources=True))]
    assert len({base, *others}) == 8


def test_memory_hits_lru_eviction_and_release(gl):
    one = PEMCache(gl, max_bytes=1).get  # just measures a set's size
    probe = one("x", _cube(0), PEMSettings(6))
    size = probe.nbytes
    cache = PEMCache(gl, max_bytes=2 * size + size // 2)
    a = cache.get("a", _cube(1), PEMSettings(6))
    assert cache.get("a", _cube(1), PEMSettings(6)) is a
    assert cache.stats.hits == 1 and cache.stats.builds == 1
    b = cache.get("b", _cube(2), PEMSettings(6))
    cache.get("a", _cube(1), PEMSettings(6))          # a is now the most recent
    cache.get("c", _cube(3), PEMSettings(6))          # evicts b, the least recently used
    assert cache.stats.evictions == 1 and cache.stats.entries == 2
    assert all(t.glo == 0 for t in b.textures)         # its GPU memory was released
    assert all(t.glo != 0 for t in a.textures)
    cache.clear()
    probe.release()


def test_disk_cache_survives_a_restart_and_ignores_corrupt_entries(gl, tmp_path):
    cube = _cube(4)
    first = PEMCache(gl, disk_dir=tmp_path)
    built = first.get("map", cube, PEMSettings(12))
    level0 = built.read_level_raw(0)
    first.clear()

    second = PEMCache(gl, disk_dir=tmp_path)           # a restarted service
    restored = second.get("map", cube, PEMSettings(12))
    assert second.stats.disk_hits == 1 and second.stats.builds == 0
    assert np.array_equal(restored.read_level_raw(0), level0)
    second.clear()

    for f in tmp_path.glob("*.npz"):                   # truncate the entry on disk
        f.write_bytes(f.read_bytes()[:100])
    third = PEMCache(gl, disk_dir=tmp_path)
    rebuilt = third.get("map", cube, PEMSettings(12))
    assert third.stats.disk_errors == 1 and third.stats.builds == 1
    assert np.array_equal(rebuilt.read_level_raw(0), level0)
    third.clear()
    fourth = PEMCache(gl, disk_dir=tmp_path)           # and the rebuilt entry replaced the bad one
    fourth.get("map", cube, PEMSettings(12))
    assert fourth.stats.disk_hits == 1
    fourth.clear()
