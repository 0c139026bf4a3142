"""Reproduce thesis Ch. 5 (2M) at a CPU budget: WindyGrid (Fig. 5.5) and MinAtar (Fig. 5.6), via ``sb3-gcrl compare``.

The runs are the ``ch5`` (WindyGrid: tabular 2M, Q-learning, EC) and ``ch5-minatar`` (TwoMemoryDQN, DQN with the
authors' network, MFEC) comparison presets, so every setting comes from ``zoo_configs/`` (``tabular_*.yml``,
``two_memory_dqn.yml``, ``dqn.yml``, ``mfec.yml``); this script only chooses the budget and the seeds and
adds the chapter's table. Each subcommand writes a comparison folder (``<out>/windygrid``, ``<out>/<game>``) with
what ``sb3-gcrl compare`` writes (``report.md``, ``curves.png``, ``memory_*.png``: Fig. 5.6's top row); ``report``
re-reads every such folder and prints, per agent, the median [min, max] return over seeds at 10/25/50/100% of
training, the mean over the first 30% / last 20% of training, and how often 2M evaluates with its EC memory
(Eq. 5.6), and draws ``<out>/<task>.png`` (median and min-max band; WindyGrid with its optimal return).

  python scripts/reproduce_ch5.py windygrid --seeds 0 1 2 3 4 --steps 100000 --eval-every 4000 --out results/ch5
  python scripts/reproduce_ch5.py minatar --game Breakout --seeds 0 1 2 --steps 600000 --eval-every 30000 \\
      --out results/ch5
  python scripts/reproduce_ch5.py report --out results/ch5

Re-running a command resumes (finished runs are kept). ``--quick`` runs the ``ch5-quick`` / ``ch5-minatar-quick``
presets (one seed, a few thousand steps: a pipeline check).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
import pandas as pd

from sb3_gcrl.compare.presets import get_preset, minatar_env_kwargs, preset_labels, run_preset, select_methods

#: fractions of training at which the table reports the return
FRACTIONS = (0.1, 0.25, 0.5, 1.0)
WINDY_ENV = "GCRL/WindyGrid-v0"


def _run(args: argparse.Namespace, preset: str, folder: Path, **overrides: object) -> int:
    """Run ``preset`` (or its ``-quick`` variant) with the command line's budget; exit code as ``sb3-gcrl compare``."""
    name = f"{preset}-quick" if args.quick else preset
    result = run_preset(
        name,
        folder,
        methods=select_methods([name], args.agents),
        seeds=args.seeds,
        n_timesteps=args.steps,
        eval_freq=args.eval_every,
        n_eval_episodes=args.eval_episodes,
        n_workers=args.workers,
        **overrides,
    )
    print(result.summary.table)
    return 1 if result.summary.failed else 0


def run_windygrid(args: argparse.Namespace) -> int:
    return _run(args, "ch5", Path(args.out) / "windygrid")


def run_minatar(args: argparse.Namespace) -> int:
    envs = [f"MinAtar/{args.game}-v1"]
    return _run(args, "ch5-minatar", Path(args.out) / args.game, envs=envs, env_kwargs=minatar_env_kwargs(args.game))


def _at(n: int, fraction: float) -> int:
    return max(int(round(fraction * n)) - 1, 0)


def summary_lines(curves: pd.DataFrame) -> list[str]:
    """The chapter's table for one comparison folder's ``curves.csv`` (metric: evaluation return).

    The evaluation before training (step 0) is left out, so the fractions and the early/late windows cover the
    evaluations made during training.
    """
    curves = curves[curves["timesteps"] > 0]
    lines = []
    methods = list(dict.fromkeys(curves["method"]))
    steps = np.sort(curves["timesteps"].unique())
    header = " ".join(f"{'@' + str(int(steps[_at(len(steps), f)])):>25s}" for f in FRACTIONS)
    lines.append(f"{'agent':15s} {header}")
    for method in methods:
        table = curves[curves["method"] == method].pivot_table(index="seed", columns="timesteps", values="mean_return")
        table = table.dropna(axis=1)  # steps every seed reached
        values, n = table.to_numpy(), table.shape[1]
        cells = []
        for fraction in FRACTIONS:
            column = values[:, _at(n, fraction)]
            cells.append(f"{np.median(column):8.2f} [{column.min():7.2f},{column.max():7.2f}]")
        early = np.median(values[:, : max(int(0.3 * n), 1)].mean(axis=1))
        late = np.median(values[:, -max(int(0.2 * n), 1) :].mean(axis=1))
        lines.append(
            f"{method:15s} " + " ".join(cells) + f"   early {early:7.2f}  late {late:7.2f}   (n={len(values)})"
        )
        memory = curves[curves["method"] == method].pivot_table(
            index="seed", columns="timesteps", values="eval_memory_is_ec"
        )
        if memory.size and memory.notna().any().any():
            share = memory.mean(axis=0).to_numpy()
            at = [_at(len(share), f) for f in FRACTIONS]
            lines.append(
                f"{'':15s} evaluates with EC (share of seeds): "
                + ", ".join(f"{int(memory.columns[i])}: {share[i]:.2f}" for i in at)
            )
    return lines


def report(args: argparse.Namespace) -> int:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sb3_gcrl.envs.windy_grid import windy_grid_optimal_value

    folders = sorted(path.parent for path in Path(args.out).glob("*/curves.csv"))
    if not folders:
        print(f"no comparison in {args.out} (run the windygrid or minatar subcommand first)", file=sys.stderr)
        return 1
    for folder in folders:
        curves = pd.read_csv(folder / "curves.csv")
        if curves.empty:
            continue
        task = folder.name
        print(f"\n== {task}: evaluation return, median [min, max] over seeds ==")
        print("(early / late: median over seeds of the mean return over the first 30% / last 20% of training)")
        print("\n".join(summary_lines(curves)))
        windy = (curves["env"] == WINDY_ENV).all()
        if windy:
            print(f"optimal expected return (value iteration): {windy_grid_optimal_value():.2f}")
        fig, ax = plt.subplots(figsize=(6, 4))
        for method in dict.fromkeys(curves["method"]):
            table = curves[curves["method"] == method].pivot_table(
                index="seed", columns="timesteps", values="mean_return"
            )
            table = table.dropna(axis=1)
            x, values = table.columns.to_numpy(), table.to_numpy()
            seeds = f"{len(values)} seed" + ("s" if len(values) > 1 else "")
            ax.plot(x, np.median(values, 0), label=f"{method} ({seeds})")
            ax.fill_between(x, values.min(0), values.max(0), alpha=0.2)
        if windy:
            ax.axhline(windy_grid_optimal_value(), color="k", ls="--", label="optimum")
        ax.set(
            title=f"{task}: greedy evaluation return\n(median over seeds, band: min-max)",
            xlabel="env steps",
            ylabel="mean return",
        )
        ax.legend()
        fig.tight_layout()
        fig.savefig(Path(args.out) / f"{task}.png", dpi=100)
        plt.close(fig)
    return 0


def _add_run_arguments(parser: argparse.ArgumentParser, preset: str, eval_episodes_help: str) -> None:
    defaults = get_preset(preset)
    parser.add_argument("--agents", "--agent", nargs="+", choices=preset_labels(preset), help="default: all")
    parser.add_argument("--seeds", "--seed", type=int, nargs="+", help=f"default: {list(defaults.seeds)}")
    parser.add_argument("--steps", type=int, help=f"env steps per run (default {defaults.n_timesteps:,})")
    parser.add_argument("--eval-every", type=int, help=f"default {defaults.eval_freq:,}")
    parser.add_argument("--eval-episodes", type=int, help=eval_episodes_help)
    parser.add_argument("--workers", type=int, help="parallel runs (default: the number of cores)")
    parser.add_argument("--quick", action="store_true", help=f"the {preset}-quick preset (pipeline check)")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    windy = sub.add_parser("windygrid", help="tabular 2M vs Q-learning vs EC (preset ch5)")
    _add_run_arguments(windy, "ch5", "greedy episodes per evaluation (default 5)")
    minatar = sub.add_parser("minatar", help="TwoMemoryDQN vs DQN vs MFEC (preset ch5-minatar)")
    minatar.add_argument("--game", default="Breakout", help="MinAtar game (sticky actions: the authors' value)")
    _add_run_arguments(minatar, "ch5-minatar", "greedy episodes per evaluation (default 5)")
    rep = sub.add_parser("report", help="tables and figures of every comparison folder in --out")
    for p in (windy, minatar, rep):
        p.add_argument("--out", default="results/ch5")
    args = parser.parse_args(argv)
    return {"windygrid": run_windygrid, "minatar": run_minatar, "report": report}[args.command](args)


if __name__ == "__main__":
    sys.exit(main())
