import numpy as np
from conftest import sun_sky_cube

from renderer.cache import PEMCache, cache_key
from renderer.lighting.filters import Filter
from renderer.lighting.pem import PEMSettings


def _cube(seed):
    return sun_sky_cube(16, (np.cos(seed), 1.0, np.sin(seed)), sun_radiance=100.0 + seed)


def test_key_changes_with_every_parameter():
    base = cache_key("abc", 16, PEMSettings(24))
    assert base == cache_key("abc", 16, PEMSettings(24))
    others = [cache_key("abd", 16, PEMSettings(24)), cache_key("abc", 32, PEMSettings(24)),
              cache_key("abc", 16, PEMSettings(48)), cache_key("abc", 16, PEMSettings(24, filter=Filter.BOX)),
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


def test_disk_cache_keeps_within_its_bytes_least_recently_used_first(gl, tmp_path):
    import os

    foreign = tmp_path / "notes.npz"                   # not the cache's: never evicted
    foreign.write_bytes(b"x" * 10)
    probe = PEMCache(gl, disk_dir=tmp_path / "probe")
    probe.get("p", _cube(0), PEMSettings(6))
    size = next((tmp_path / "probe").glob("*.npz")).stat().st_size
    probe.clear()

    cache = PEMCache(gl, disk_dir=tmp_path, disk_max_bytes=2 * size + size // 2)
    keys = {}
    for t, name in enumerate("abc"):
        cache.get(name, _cube(t + 1), PEMSettings(6))
        keys[name] = cache_key(name, 16, PEMSettings(6))
        os.utime(tmp_path / f"{keys[name]}.npz", (1000 + t, 1000 + t))   # distinct times, a before b before c
        cache.clear()                                  # the next get reads the disk, not GPU memory
    # Three entries of 2.5 allowed: writing c evicted a, the least recently used.
    assert cache.stats.disk_evictions == 1
    assert not (tmp_path / f"{keys['a']}.npz").exists() and foreign.exists()
    cache.get("b", _cube(2), PEMSettings(6))           # a disk hit renews b's time
    assert cache.stats.disk_hits == 1
    cache.clear()
    cache.get("d", _cube(4), PEMSettings(6))           # so writing d evicts c, not b
    cache.clear()
    left = {p.name for p in tmp_path.glob("*.npz")}
    assert left == {"notes.npz", f"{keys['b']}.npz", f"{cache_key('d', 16, PEMSettings(6))}.npz"}
    assert cache.stats.disk_evictions == 2


def test_an_entry_larger_than_the_disk_budget_is_not_written_and_evicts_nothing(gl, tmp_path):
    PEMCache(gl, disk_dir=tmp_path).get("a", _cube(1), PEMSettings(6))
    (a,) = tmp_path.glob("*.npz")
    cache = PEMCache(gl, disk_dir=tmp_path, disk_max_bytes=a.stat().st_size)
    cache.get("b", _cube(2), PEMSettings(12))    # twice a's size: it alone would not fit
    assert list(tmp_path.glob("*.npz")) == [a] and cache.stats.disk_too_large == 1
    cache.clear()


def test_an_entry_under_another_sets_name_is_rebuilt_not_trusted(gl, tmp_path):
    cache = PEMCache(gl, disk_dir=tmp_path)
    cache.get("a", _cube(1), PEMSettings(6))
    want = np.array(cache.get("b", _cube(2), PEMSettings(6)).regions.directions)
    path_a, path_b = (tmp_path / f"{cache_key(h, 16, PEMSettings(6))}.npz" for h in "ab")
    path_b.write_bytes(path_a.read_bytes())      # a's set copied under b's key
    cache.clear()
    fresh = PEMCache(gl, disk_dir=tmp_path)
    pems = fresh.get("b", _cube(2), PEMSettings(6))
    assert fresh.stats.disk_key_mismatches == 1 and fresh.stats.builds == 1 and fresh.stats.disk_hits == 0
    np.testing.assert_array_equal(pems.regions.directions, want)   # b's lights, not a's
    fresh.clear()
    again = PEMCache(gl, disk_dir=tmp_path)      # the rebuilt entry replaced the copy
    again.get("b", _cube(2), PEMSettings(6))
    assert again.stats.disk_hits == 1 and again.stats.disk_key_mismatches == 0
    again.clear()


def test_orphaned_temporaries_are_removed_when_a_cache_opens_and_live_ones_kept(gl, tmp_path):
    import fcntl
    import os

    orphan = tmp_path / ".tmp-orphan"
    orphan.write_bytes(b"\0" * 1000)            # its writer was killed: nobody holds its lock
    live = tmp_path / ".tmp-live"
    fd = os.open(live, os.O_CREAT | os.O_WRONLY)
    fcntl.flock(fd, fcntl.LOCK_EX)               # a writer in another process, still writing
    try:
        cache = PEMCache(gl, disk_dir=tmp_path)
        assert not orphan.exists() and live.exists()
        assert (cache.stats.temporaries_removed, cache.stats.temporary_bytes_removed) == (1, 1000)
    finally:
        os.close(fd)
