"""The Ray backend runs the same episodes as the local pool (a local Ray instance with 2 CPUs)."""

import pytest

from superex_deploy.cli import main

ray = pytest.importorskip("ray")


@pytest.mark.slow
def test_a_benchmark_on_ray_gives_the_local_pools_results(deterministic_episodes, tmp_path):
    base = ["benchmark", "--maps", "50052750", "--planners", "nearest,upen,mapex", "--steps", "80", "--jobs", "2"]
    assert main(base + ["--out", str(tmp_path / "local")]) == 0
    assert main(base + ["--backend", "ray", "--out", str(tmp_path / "ray")]) == 0
    assert deterministic_episodes(tmp_path / "ray") == deterministic_episodes(tmp_path / "local")
    assert len(deterministic_episodes(tmp_path / "ray")) == 12
    assert not ray.is_initialized()  # the local instance was shut down


def test_ray_options_are_checked(tmp_path, capsys):
    assert main(["benchmark", "--maps", "50052750", "--planners", "nearest", "--address", "auto",
                 "--out", str(tmp_path / "x")]) == 2
    assert "--address needs --backend ray" in capsys.readouterr().err


@pytest.mark.slow
def test_training_data_generated_on_ray_is_the_local_pools(tmp_path):
    from superex_deploy.parallel import LocalBackend, RayBackend
    from superex_train.generate import GenerationConfig, generate_pix2pix

    cfg = GenerationConfig(maps=("0510030965_A-40",), episodes_per_map=2, steps=30, sample_every=10, window_cells=48,
                           jobs=2)
    local = generate_pix2pix(tmp_path / "local", cfg, progress=False, backend=LocalBackend(2))
    on_ray = generate_pix2pix(tmp_path / "ray", cfg, progress=False, backend=RayBackend(num_cpus=2))
    assert on_ray.count == local.count > 0 and on_ray.data_sha256 == local.data_sha256
