"""Kill and resume ``sb3-gcrl train`` runs at random points; report runs survived and work lost.

For each algorithm and trial, a short run with ``--save-freq`` starts; after its first checkpoint, at a random
moment, it gets SIGINT (Ctrl-C: a checkpoint at the interruption, exit code 130) or SIGKILL (no warning: the steps
after the last checkpoint are lost). ``sb3-gcrl train --resume`` then continues it, and with probability 1/2 that
resume is interrupted the same way once more, before a last resume finishes the run. A run *survived* when it ends
with its full budget: the final model at the run's step budget (or within one ``train_freq`` chunk past it, as
SB3's own ``learn`` ends when the budget is not a multiple of ``train_freq``), one evaluation per ``--eval-freq``
steps in ``evaluations.npz`` (none lost, none twice), a readable monitor CSV and no partial checkpoint left
behind. *Work lost* per interruption is the env steps of the monitor CSV at that moment beyond the checkpoint the
run resumed from (steps of segments still open are not counted).

Algorithms (tiny budgets and networks, so a trial takes well under a minute of one core):

* ``sac``: MoReFree-SAC, reset-free (Back-and-Forth Go-Explore wrappers, task-relevant HER) on PointUMaze;
* ``morefree``: the world-model MoReFree agent (CPU preset, tiny budget) on reset-free PointUMaze;
* ``cec``: continuous episodic control on episodic PointUMaze (the memory lives in the model file).

Example (what the docs quote)::

    python scripts/fault_injection.py --trials 4 --seed 0
"""

from __future__ import annotations

import argparse
import json
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

RUNS: dict[str, dict[str, Any]] = {
    "sac": {
        "env": "GCRL/PointUMazeGoal-v0",
        "arguments": [
            "--algo", "sac", "-n", "4000", "--save-freq", "500",
            "-params", "learning_starts:1000", "batch_size:32", "policy_kwargs:dict(net_arch=[32])",
        ],
    },
    "morefree": {
        "env": "GCRL/PointUMazeGoal-v0",
        "arguments": [
            "--algo", "morefree", "-n", "1600", "--save-freq", "200",
            "-params", "learning_starts:1200", "compile_train_step:False",
        ],
    },
    "cec": {
        "env": "GCRL/PointUMaze-v0",
        "arguments": ["--algo", "cec", "-n", "6000", "--save-freq", "1000"],
    },
}  # fmt: skip
EVAL_FREQ = 500


def monitor_steps(run_dir: Path) -> int:
    """Env steps of the episodes/segments the run's monitor CSVs have recorded."""
    total = 0
    for path in run_dir.glob("*.monitor.csv"):
        lines = path.read_text().splitlines()[2:]
        total += sum(int(line.split(",")[1]) for line in lines if line.count(",") >= 2)
    return total


def checkpoint_steps(run_dir: Path) -> int | None:
    """Steps of the run's newest complete checkpoint, None without one."""
    latest = run_dir / "checkpoints" / "latest"
    if not latest.is_file():
        return None
    manifest = run_dir / "checkpoints" / latest.read_text().strip() / "checkpoint.json"
    return int(json.loads(manifest.read_text())["num_timesteps"]) if manifest.is_file() else None


def start(arguments: list[str], cwd: Path, log: Path) -> subprocess.Popen[bytes]:
    with log.open("ab") as out:
        command = [sys.executable, "-m", "sb3_gcrl", "train", *arguments]
        return subprocess.Popen(command, cwd=cwd, stdout=out, stderr=out)


def interrupt(process: subprocess.Popen[bytes], run_dir: Path, rng: np.random.Generator, after: int | None) -> dict:
    """Wait for a checkpoint newer than ``after``, then a random 0-3 s, then SIGINT or SIGKILL the run."""
    while process.poll() is None and (checkpoint_steps(run_dir) or -1) <= (after or -1):
        time.sleep(0.05)
    time.sleep(float(rng.uniform(0.0, 3.0)))
    if process.poll() is not None:
        return {"signal": None, "rc": process.returncode}
    sig = signal.SIGINT if rng.random() < 0.5 else signal.SIGKILL
    steps_seen = monitor_steps(run_dir)
    process.send_signal(sig)
    rc = process.wait(timeout=600)
    resumed_from = checkpoint_steps(run_dir) or 0
    return {"signal": sig.name, "rc": rc, "lost": max(0, steps_seen - resumed_from), "resumed_from": resumed_from}


def survived(run_dir: Path, env_name: str, budget: int) -> tuple[bool, str]:
    """Whether the finished run has everything (see the module's docstring), and what is missing if not."""
    from stable_baselines3.common.monitor import load_results
    from stable_baselines3.common.save_util import load_from_zip_file

    model = run_dir / f"{env_name}.zip"
    if not model.is_file():
        return False, "no final model"
    steps = load_from_zip_file(model)[0]["num_timesteps"]
    if not budget <= steps < budget + 4:  # SB3 collects train_freq (up to 4 here) steps at a time
        return False, f"final model at {steps} steps"
    with np.load(run_dir / "evaluations.npz") as data:
        timesteps = data["timesteps"].tolist()
    if timesteps != list(range(EVAL_FREQ, budget + 1, EVAL_FREQ)):
        return False, f"evaluations at {timesteps}"
    load_results(str(run_dir))
    if [path for path in (run_dir / "checkpoints").iterdir() if path.name.startswith(".")]:
        return False, "a partial checkpoint was left"
    return True, ""


def trial(algo: str, seed: int, rng: np.random.Generator, work: Path) -> dict:
    spec = RUNS[algo]
    env_name = spec["env"].replace("/", "-")
    arguments = [*spec["arguments"], "--env", spec["env"], "--eval-freq", str(EVAL_FREQ), "--eval-episodes", "1"]
    arguments += ["-f", "logs", "--seed", str(seed)]
    cwd = work / f"{algo}_{seed}"
    cwd.mkdir(parents=True)
    log = cwd / "output.txt"
    run_dir = cwd / "logs" / algo / f"{env_name}_1"
    budget = int(arguments[arguments.index("-n") + 1])
    started = time.perf_counter()
    events = [interrupt(start(arguments, cwd, log), run_dir, rng, None)]
    resumes = 0
    if rng.random() < 0.5:  # interrupt the resumed run once more
        resumes += 1
        events.append(interrupt(start(["--resume", str(run_dir)], cwd, log), run_dir, rng, checkpoint_steps(run_dir)))
    final = start(["--resume", str(run_dir)], cwd, log) if checkpoint_steps(run_dir) != budget else None
    if final is not None:
        resumes += 1
        final.wait(timeout=1800)
    ok, why = survived(run_dir, env_name, budget)
    expected_rc = {"SIGINT": 130, "SIGKILL": -signal.SIGKILL, None: 0}
    bad_rc = [e for e in events if e["rc"] != expected_rc[e["signal"]]]
    if bad_rc:
        ok, why = False, f"exit codes {bad_rc}"
    return {
        "algo": algo,
        "seed": seed,
        "interruptions": [e["signal"] for e in events if e["signal"]],
        "lost": [e["lost"] for e in events if e["signal"]],
        "sigint_lost": [e["lost"] for e in events if e["signal"] == "SIGINT"],
        "resumes": resumes,
        "survived": ok,
        "why": why,
        "wall_s": time.perf_counter() - started,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--algos", nargs="+", default=list(RUNS), choices=list(RUNS))
    parser.add_argument("--trials", type=int, default=4, help="trials per algorithm")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--keep", type=Path, default=None, help="keep the runs in this folder (default: a temp one)")
    args = parser.parse_args()
    rng = np.random.default_rng(args.seed)
    with tempfile.TemporaryDirectory() as temp:
        work = args.keep or Path(temp)
        results = []
        for algo in args.algos:
            for i in range(args.trials):
                result = trial(algo, args.seed * 1000 + i, rng, work)
                print(json.dumps(result), flush=True)
                results.append(result)
    print(f"\n{'algorithm':10s} {'runs':>4s} {'survived':>8s} {'SIGINT':>6s} {'SIGKILL':>7s} "
          f"{'lost after SIGINT':>17s} {'lost after SIGKILL (median, max)':>32s} {'wall s/run':>10s}")  # fmt: skip
    for algo in args.algos:
        rows = [r for r in results if r["algo"] == algo]
        signals = [s for r in rows for s in r["interruptions"]]
        kill_lost = [lost for r in rows for s, lost in zip(r["interruptions"], r["lost"]) if s == "SIGKILL"]
        int_lost = [lost for r in rows for lost in r["sigint_lost"]]
        kill = f"{np.median(kill_lost):.0f}, {max(kill_lost)}" if kill_lost else "-"
        print(
            f"{algo:10s} {len(rows):4d} {sum(r['survived'] for r in rows):8d} {signals.count('SIGINT'):6d} "
            f"{signals.count('SIGKILL'):7d} {max(int_lost) if int_lost else '-':>17} {kill:>32s} "
            f"{np.median([r['wall_s'] for r in rows]):10.1f}"
        )
    failed = [r for r in results if not r["survived"]]
    for r in failed:
        print(f"FAILED {r['algo']} seed {r['seed']}: {r['why']}")
    sys.exit(1 if failed else 0)


if __name__ == "__main__":
    main()
