"""The installed package stands alone: a wheel built from this tree, installed into a fresh venv, trains with the
zoo configs it ships (no clone needed)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def see_installed_dependencies(python: Path) -> None:
    """Let the venv of ``python`` import what the running interpreter has installed, after its own packages.

    ``venv --system-site-packages`` is not enough: run from inside a virtual or conda env, it exposes the base
    interpreter's packages, not that env's. A ``.pth`` file listing every site directory on the running interpreter's
    path works from a venv, a conda env and a bare interpreter alike. Plain path lines do not run the ``.pth`` files
    of those directories, so an editable install of this tree there stays invisible: sb3_gcrl comes from the wheel.
    """
    site_dirs = [entry for entry in sys.path if Path(entry).name in ("site-packages", "dist-packages")]
    purelib = subprocess.run(
        [str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout.strip()
    (Path(purelib) / "installed_dependencies.pth").write_text("\n".join(site_dirs) + "\n")


def run_python(python: Path, code: str, cwd: Path) -> str:
    """What ``python -c code`` prints, run in ``cwd``."""
    return subprocess.run([str(python), "-c", code], cwd=cwd, check=True, capture_output=True, text=True).stdout


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
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    python, launcher = venv / "bin" / "python", venv / "bin" / "sb3-gcrl"
    see_installed_dependencies(python)
    subprocess.run([str(python), "-m", "pip", "install", "--no-deps", "--no-index", str(wheels[0])], check=True)
    work = tmp_path / "elsewhere"  # not the clone: nothing to find by relative path
    work.mkdir()
    location = run_python(
        python, "import sb3_gcrl, sb3_gcrl.cli as c; print(sb3_gcrl.__file__); print(c.ZOO_CONFIGS_DIR)", work
    )
    assert all(str(venv) in line for line in location.split()), location  # the wheel's copy, not this tree
    import stable_baselines3

    dependency = run_python(python, "import stable_baselines3; print(stable_baselines3.__file__)", work)
    assert dependency.strip() == stable_baselines3.__file__  # this env's dependencies (a venv's or conda env's own)
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
