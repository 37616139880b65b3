"""The package as a user installs it: every package folder in the wheel, the models and maps inside it, an installed
``superex`` that runs the SuperEx pipeline from any folder."""

import os
import subprocess
import sys
import sysconfig
import tomllib
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_every_package_folder_is_listed_in_pyproject():
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = {".".join(p.parent.relative_to(ROOT).parts) for top in ("superex_deploy", "superex_train")
             for p in (ROOT / top).rglob("__init__.py")}
    assert listed == found | {"superex_deploy.models"}


@pytest.mark.slow
def test_the_wheel_carries_the_models_and_runs_the_pipeline_outside_the_checkout(tmp_path):
    wheels = tmp_path / "wheels"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(wheels), str(ROOT)],
                   check=True, cwd=tmp_path)
    (wheel,) = wheels.glob("superex-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    manifest_files = {"superex_deploy/models/manifest.json", "superex_deploy/models/pix2pix.onnx",
                      "superex_deploy/models/lama_bp_0.onnx", "superex_deploy/models/lama_los_2.onnx",
                      "superex_deploy/data/kth/manifest.json", "superex_deploy/data/kth/eval/50052750.png"}
    assert manifest_files <= names
    assert not any("checkpoints" in name for name in names)  # the torch checkpoints stay in the repository

    # A fresh venv whose only superex is the wheel; its dependencies come from this environment's site-packages
    # (appended through a .pth file, so nothing is downloaded).
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python = venv / "bin" / "python"
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          capture_output=True, text=True, check=True).stdout.strip()
    (Path(site) / "host_dependencies.pth").write_text(sysconfig.get_paths()["purelib"] + "\n")
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--no-deps", "--no-index", str(wheel)], check=True)
    outside = tmp_path / "elsewhere"
    outside.mkdir()
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "SUPEREX_MODELS")}
    env["NUMBA_NUM_THREADS"] = "1"
    where = subprocess.run([str(python), "-c", "import superex_deploy.onboard.prediction.inference as i; print(i.DEFAULT_MODEL_DIR)"],
                           capture_output=True, text=True, check=True, cwd=outside, env=env).stdout.strip()
    assert Path(where).is_relative_to(Path(site)), where
    run = subprocess.run([str(venv / "bin" / "superex"), "explore", "--map", "50052750", "--planner", "superex",
                          "--predictor", "lama_bp", "--spad", "--steps", "3", "--out", str(outside / "run")],
                         capture_output=True, text=True, cwd=outside, env=env)
    assert run.returncode == 0, run.stderr[-2000:]
    assert (outside / "run" / "metrics.json").is_file()
