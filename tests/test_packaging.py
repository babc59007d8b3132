"""A normal (non-editable) install carries the assets: build the wheel, install it, load the model."""

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
    for package in sorted((ROOT / "hexgym").glob("*/__init__.py")):  # every subpackage, e.g. hexgym.planning
        assert package.relative_to(ROOT).as_posix() in names, package.parent.name
    subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--no-deps", "-t", target, wheel], check=True)
    code = "import hexgym.machine.physics as h, sys; p = h.ExcavatorPhysics(scene=True); print(h.__file__)"
    env = {**os.environ, "PYTHONPATH": str(target)}
    out = subprocess.run([sys.executable, "-c", code], cwd=tmp_path, env=env, capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().startswith(str(target))
