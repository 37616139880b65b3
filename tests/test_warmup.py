from superex_deploy.cli import main
from superex_deploy.commands import warmup


def test_warmup_compiles_and_loads_everything_and_a_cold_explore_says_why_it_waits(tmp_path, capsys, monkeypatch):
    assert main(["warmup"]) == 0
    assert "superex warmup: done in" in capsys.readouterr().out
    assert warmup.numba_cache_is_warm()  # the warm-up ran every kernel: numba cached them
    monkeypatch.setattr(warmup, "numba_cache_is_warm", lambda: False)
    argv = ["explore", "--pipeline", "nearest", "--map", "50052750", "--steps", "2", "--gif-every", "10",
            "--predictor", "observed"]
    assert main(argv + ["--spad", "--out", str(tmp_path / "spad")]) == 0
    assert "compiling the numba kernels" in capsys.readouterr().err
    # Without SPAD the slow kernels never run, so a cold cache says nothing (the notice would be wrong).
    assert main(argv + ["--out", str(tmp_path / "los")]) == 0
    assert "compiling the numba kernels" not in capsys.readouterr().err
