"""A normal (non-editable) install carries both packages and their data: build the wheel, install it, load the
model, read the packaged hyperparameters."""

import os
import subprocess
import sys
import zipfile
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def test_wheel_installs_with_assets(tmp_path):
    wheel_dir, target = tmp_path / "wheel", tmp_path / "site"
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-q", "-w", wheel_dir, ROOT],
        check=True,
        cwd=tmp_path,
    )
    (wheel,) = wheel_dir.glob("hexgym-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    for required in ("hexgym/assets/cat325.xml", "hexgym/assets/scene.xml", "hexgym/assets/meshes/bucket.stl"):
        assert required in names
    for package in sorted([*(ROOT / "hexgym").glob("*/__init__.py"), *(ROOT / "hexgym_lab").glob("*/__init__.py")]):
        assert package.relative_to(ROOT).as_posix() in names, package.parent.name  # every subpackage
    for name in ("ppo", "ppo_finetune", "ppo_scratch", "sac"):  # the lab's packaged rl-zoo3 hyperparameters
        assert f"hexgym_lab/hyperparams/{name}.yml" in names
    assert "hexgym_lab/cli.py" in names and "hexgym_lab/__main__.py" in names
    assert not [n for n in names if n.startswith(("experiments/", "tests/", "training/"))]  # not installed
    (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
    assert "hexgym = hexgym_lab.cli:main" in zipfile.ZipFile(wheel).read(entry_points).decode()
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "-t", target, wheel], check=True)
    code = (
        "import hexgym.machine.physics as h, sys; p = h.ExcavatorPhysics(scene=True); print(h.__file__)\n"
        "from hexgym_lab.agents.hyperparams import load_hyperparams; print(load_hyperparams('ppo')['n_envs'] > 0)"
    )
    env = {**os.environ, "PYTHONPATH": str(target)}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    physics_file, hyperparams_read = out.stdout.split()
    assert physics_file.startswith(str(target)) and hyperparams_read == "True"
