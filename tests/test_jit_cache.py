"""srmpc.sim.jit_cache: a change to any kernel source, in a subpackage too, drops every numba cache file below."""

from __future__ import annotations

from srmpc.sim import jit_cache


def test_an_edit_in_a_subpackage_changes_the_digest_and_drops_nested_caches(tmp_path, monkeypatch):
    sim, mpc = tmp_path / "sim", tmp_path / "mpc"
    (mpc / "solvers" / "__pycache__").mkdir(parents=True)
    (sim / "__pycache__").mkdir(parents=True)
    (sim / "engine.py").write_text("a = 1\n")
    kernel = mpc / "solvers" / "ipm.py"
    kernel.write_text("b = 1\n")
    monkeypatch.setattr(jit_cache, "_PACKAGE_ROOT", tmp_path)
    monkeypatch.setattr(jit_cache, "KERNEL_SOURCE_DIRS", (sim, mpc))
    assert jit_cache.drop_stale_numba_cache()  # no stamp yet
    cached = [mpc / "solvers" / "__pycache__" / "ipm.solve-1.py311.nbi", sim / "__pycache__" / "engine.step.nbc"]
    for path in cached:
        path.write_text("")
    before = jit_cache.sources_digest()
    assert not jit_cache.drop_stale_numba_cache() and all(path.exists() for path in cached)
    kernel.write_text("b = 2\n")  # an edit two levels down
    assert jit_cache.sources_digest() != before
    assert jit_cache.drop_stale_numba_cache()
    assert not any(path.exists() for path in cached)
