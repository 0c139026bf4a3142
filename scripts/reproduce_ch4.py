"""Thesis Ch. 4 learning comparison: CEC vs SAC (vs EMAC) on GrowingTree, the navigation tasks, sparse MountainCar.

The runs are the ``ch4`` comparison preset of ``sb3-gcrl compare`` (``quick`` is its GrowingTree part), or with
``--preset ch4-navigation`` Fig. 4.3's three-way comparison (CEC, SAC, EMAC on PointUMaze, Point4Rooms with
sub-goals, PointGoal, CarGoal): hyperparameters come from ``zoo_configs/cec.yml``, ``zoo_configs/sac.yml`` and
``zoo_configs/emac.yml`` (what ``sb3-gcrl train`` uses),
and every ``--eval-freq`` steps each agent is evaluated greedily for ``--eval-episodes`` episodes on a separate
env (success: ``info["is_success"]``; all four tasks reward only reaching the goal). This script picks tasks,
algorithms, budget and seeds, and prints the chapter's table: per task and algorithm the mean (and per-seed
values) of the evaluation success at each checkpoint, the first step with success 1.0 per seed, and the median
wall time per run. The comparison folder holds the report and ``curves.png`` (one panel per task, mean over seeds
with a 95% bootstrap band).

Example (the budgets of docs/results.md)::

    python scripts/reproduce_ch4.py --tasks GrowingTree --algos cec --seeds 0 1 2 3 4 --budget 5000 --eval-freq 500
    python scripts/reproduce_ch4.py --tasks PointUMaze Point4Rooms MountainCar --algos cec sac \\
        --seeds 0 1 2 3 4 --budget 100000 --eval-freq 10000 --out results/ch4_100k

    python scripts/reproduce_ch4.py --preset ch4-navigation --seeds 0 1 2 3 4 --out results/ch4_navigation

Re-running resumes; ``--table-only`` re-reads ``--out``; ``--quick`` runs the preset's ``-quick`` version.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import pandas as pd

from sb3_gcrl.compare.presets import preset_labels, run_preset, select_methods

PRESETS = ("ch4", "ch4-navigation")

#: short task names of the command line
TASKS = {
    "GrowingTree": "GCRL/GrowingTree-v0",
    "PointUMaze": "GCRL/PointUMaze-v0",
    "Point4Rooms": "GCRL/Point4Rooms-v0",
    "Point4RoomsSubgoals": "GCRL/Point4RoomsSubgoals-v0",
    "PointGoal": "GCRL/PointGoal-v0",
    "CarGoal": "GCRL/CarGoal-v0",
    "MountainCar": "GCRL/SparseMountainCarContinuous-v0",
}


def print_table(curves: pd.DataFrame) -> None:
    """Success at each checkpoint (mean; per seed), first step with success 1.0, evaluation episode length at the
    last checkpoint (the tasks end at the goal, so shorter is a more direct path; the time limit when never reached),
    median wall time per run."""
    print(
        "\n| task | algo | seeds | success at steps (mean; per seed) | first step with success 1.0 "
        "| episode length at the end (mean; per seed) | wall s/run |"
    )
    print("|---|---|---|---|---|---|---|")
    names = {env_id: name for name, env_id in TASKS.items()}
    for (env_id, method), runs in curves.groupby(["env", "method"], sort=False):
        table = runs.pivot_table(index="seed", columns="timesteps", values="success_rate").dropna(axis=1)
        cells = [
            f"{int(step)}: {table[step].mean():.2f} ({', '.join(f'{v:.1f}' for v in table[step])})"
            for step in table.columns
        ]
        first = [next((int(step) for step, v in row.items() if v >= 1.0), None) for _, row in table.iterrows()]
        solved = sum(step is not None for step in first)
        wall = runs.groupby("seed")["wall_time_s"].max().median()
        lengths = runs.pivot_table(index="seed", columns="timesteps", values="mean_length").iloc[:, -1]
        print(
            f"| {names.get(env_id, env_id)} | {method} | {len(table)} | {'<br>'.join(cells)} | "
            f"{solved}/{len(table)} solved: {first} | {lengths.mean():.0f} ({', '.join(f'{v:.0f}' for v in lengths)}) "
            f"| {wall:.0f} |"
        )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", choices=PRESETS, default="ch4", help="ch4: CEC vs SAC; ch4-navigation: Fig. 4.3")
    parser.add_argument("--tasks", nargs="+", choices=list(TASKS), help="default: the preset's tasks")
    labels = sorted({label for name in PRESETS for label in preset_labels(name)})
    parser.add_argument("--algos", nargs="+", choices=labels, help="default: the preset's methods")
    parser.add_argument("--seeds", nargs="+", type=int, help="default: the preset's")
    parser.add_argument("--budget", type=int, help="env steps per run (default: the preset's)")
    parser.add_argument("--eval-freq", type=int, help="default: the preset's")
    parser.add_argument("--eval-episodes", type=int, help="default: the preset's")
    parser.add_argument("--workers", type=int, help="parallel runs (default: the number of cores)")
    parser.add_argument("--out", type=Path, default=Path("results/ch4"))
    parser.add_argument("--table-only", action="store_true", help="only print the table of the runs in --out")
    parser.add_argument("--quick", action="store_true", help="the ch4-quick preset (pipeline check)")
    args = parser.parse_args(argv)
    failed = False
    if not args.table_only:
        preset = f"{args.preset}-quick" if args.quick else args.preset
        result = run_preset(
            preset,
            args.out,
            methods=select_methods([preset], args.algos),
            envs=[TASKS[task] for task in args.tasks] if args.tasks else None,
            seeds=args.seeds,
            n_timesteps=args.budget,
            eval_freq=args.eval_freq,
            n_eval_episodes=args.eval_episodes,
            n_workers=args.workers,
        )
        print(result.summary.table)
        failed = bool(result.summary.failed)
    if not (args.out / "curves.csv").is_file():
        print(f"no comparison in {args.out}", file=sys.stderr)
        return 1
    curves = pd.read_csv(args.out / "curves.csv")
    if curves["success_rate"].isna().any():
        print("an env of this comparison does not report is_success", file=sys.stderr)
        return 1
    print_table(curves)
    print(f"curves: {args.out / 'curves.png'}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
