"""runtime: the CUDA driver version as recorded in every output's provenance."""

from warp_tensegrity.runtime import _driver_text


def test_driver_text_accepts_warp_tuple_and_int_forms():
    # Warp 1.19 returns (major, minor); older releases returned 1000*major + 10*minor
    assert _driver_text((13, 0)) == "13.0"
    assert _driver_text((12, 8)) == "12.8"
    assert _driver_text(12080) == "12.8"
    assert _driver_text(None) == "none"


def test_preload_imports_in_a_daemon_thread_and_leaves_failures_to_the_importer():
    """The output's libraries are imported beside the run's start (runtime.preload): in a daemon
    thread, which ends; a module that cannot be imported raises nothing there (the code that needs
    it words the error); the run command starts it, a dry run does not."""
    import sys

    from warp_tensegrity import runtime

    sys.modules.pop("colorsys", None)
    t = runtime.preload(("colorsys", "warp_tensegrity_no_such_module"))
    t.join(timeout=30)
    assert t.daemon and not t.is_alive() and t.name == "warp-tensegrity-preload"
    assert "colorsys" in sys.modules and "warp_tensegrity_no_such_module" not in sys.modules


def test_the_run_command_preloads_the_output_stack_and_a_dry_run_does_not(monkeypatch, tmp_path):
    from warp_tensegrity import cli

    started = []
    monkeypatch.setattr(cli, "preload", lambda *a, **k: started.append(a))
    monkeypatch.setattr(cli, "init_warp", lambda **k: (_ for _ in ()).throw(cli.WarpSetupError("stop here")))
    spec = tmp_path / "s.toml"
    spec.write_text('[sweep]\ngrid = { v0 = [0.01] }\n')
    assert cli.main(["run", str(spec), "-o", str(tmp_path / "o.nc"), "--dry-run"]) != 0 and started == []
    assert cli.main(["run", str(spec), "-o", str(tmp_path / "o.nc")]) != 0 and len(started) == 1
