"""The installed package stands alone: a wheel built from this tree, installed into a fresh venv, trains with the
zoo configs it ships (no clone needed)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_wheel_installs_into_a_fresh_venv_and_trains_with_its_shipped_config(tmp_path: Path):
    # the wheel, built from a copy of the tree (the build leaves build/ behind) without build isolation
    source = tmp_path / "source"
    junk = shutil.ignore_patterns(".git", "build", "dist", "*.egg-info", "results", "logs", "__pycache__", ".*cache")
    shutil.copytree(ROOT, source, symlinks=True, ignore=junk)
    subprocess.run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "-w", str(tmp_path), str(source)],
        check=True,
        capture_output=True,
    )
    wheels = list(tmp_path.glob("sb3_gcrl-*.whl"))
    assert len(wheels) == 1
    # a fresh venv that sees the installed dependencies but gets sb3_gcrl only from the wheel
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--system-site-packages", str(venv)], check=True)
    python, launcher = venv / "bin" / "python", venv / "bin" / "sb3-gcrl"
    subprocess.run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", str(wheels[0])], check=True)
    work = tmp_path / "elsewhere"  # not the clone: nothing to find by relative path
    work.mkdir()
    location = subprocess.run(
        [str(python), "-c", "import sb3_gcrl, sb3_gcrl.cli as c; print(sb3_gcrl.__file__); print(c.ZOO_CONFIGS_DIR)"],
        cwd=work,
        check=True,
        capture_output=True,
        text=True,
    ).stdout.split()
    assert all(str(venv) in line for line in location), location  # the wheel's copy, not this tree
    train = subprocess.run(
        [str(launcher), "train", "--algo", "cec", "--env", "GCRL/GrowingTree-v0", "-n", "500", "-f", "logs"],
        cwd=work,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert train.returncode == 0, train.stdout[-2000:] + train.stderr[-2000:]
    assert str(venv) in train.stdout  # "Loading hyperparameters from: <venv>/.../zoo_configs/cec.yml"
    assert list((work / "logs" / "cec").glob("GCRL-GrowingTree-v0_1/*.zip"))
