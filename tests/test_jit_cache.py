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


def test_precompile_runs_every_short_run_on_a_cold_cache_and_nothing_on_a_warm_one(tmp_path, monkeypatch):
    from srmpc import precompile

    started = []
    monkeypatch.setattr(precompile, "run_once", lambda overrides, output_dir: started.append(overrides))
    monkeypatch.setattr(precompile, "PACKAGE_ROOT", tmp_path)  # no index file here: cold
    assert precompile.precompile(jobs=2) and sorted(started) == sorted(precompile.RUNS)
    (tmp_path / "mpc" / "__pycache__").mkdir(parents=True)
    (tmp_path / "mpc" / "__pycache__" / "compiled_step.srmpc_step-231.py311.nbi").write_text("")
    started.clear()
    assert not precompile.precompile(jobs=2) and started == []


def test_precompile_names_a_failed_run_and_a_bad_jobs_value(capsys, monkeypatch):
    from srmpc import precompile

    monkeypatch.setattr(precompile, "RUNS", (("controller=srmpc", "evaluation.episodes=abc"),))
    monkeypatch.setattr(precompile, "cache_is_warm", lambda: False)
    assert precompile.main(["--jobs", "1"]) == 1
    assert "evaluation.episodes=abc" in capsys.readouterr().err
    try:
        precompile.main(["--jobs", "0"])
    except SystemExit as exit_:
        assert exit_.code == 2 and "--jobs=0: must be >= 1" in capsys.readouterr().err
    else:
        raise AssertionError("--jobs=0 accepted")
