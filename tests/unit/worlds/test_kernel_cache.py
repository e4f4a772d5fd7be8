"""worlds.kernel_cache: a module's cached numba kernels go when a source they inline changes."""

from __future__ import annotations

from worlds.kernel_cache import STAMP_SUFFIX, drop_stale_kernels


def _module(tmp_path):
    (tmp_path / "walk.py").write_text("def walk(): return 1\n")
    (tmp_path / "camera.py").write_text("from walk import walk\n")
    cache = tmp_path / "__pycache__"
    cache.mkdir()
    return str(tmp_path / "camera.py"), cache


def _kernels(cache):
    for name in ("camera.render-10.py311.nbi", "camera.render-10.py311.1.nbc"):
        (cache / name).write_bytes(b"compiled")
    (cache / "camera.cpython-311.pyc").write_bytes(b"bytecode")
    (cache / "walk.walk-1.py311.nbi").write_bytes(b"compiled")


def test_kernels_stay_while_the_inlined_source_is_unchanged_and_go_when_it_changes(tmp_path):
    module, cache = _module(tmp_path)
    _kernels(cache)
    drop_stale_kernels(module, ["walk.py"])          # no stamp yet: the cache is of unknown sources
    assert {p.name for p in cache.iterdir()} == {f"camera{STAMP_SUFFIX}", "camera.cpython-311.pyc",
                                                  "walk.walk-1.py311.nbi"}
    _kernels(cache)                                    # numba compiles and caches again
    assert drop_stale_kernels(module, ["walk.py"]) is False
    assert (cache / "camera.render-10.py311.nbi").exists()
    (tmp_path / "walk.py").write_text("def walk(): return 2\n")      # the inlined walk is edited
    assert drop_stale_kernels(module, ["walk.py"]) is True
    assert not (cache / "camera.render-10.py311.nbi").exists()
    assert not (cache / "camera.render-10.py311.1.nbc").exists()
    assert (cache / "walk.walk-1.py311.nbi").exists()        # other modules' kernels are theirs
    assert (cache / "camera.cpython-311.pyc").exists()


def test_an_unreadable_source_leaves_the_cache_alone(tmp_path):
    module, cache = _module(tmp_path)
    _kernels(cache)
    assert drop_stale_kernels(module, ["missing.py"]) is False
    assert (cache / "camera.render-10.py311.nbi").exists()
