"""Reproduce the reset-free comparisons of thesis Ch. 3 (Fig. 3.4, Fig. 3.5) on PointUMaze and Tabletop.

The runs are the ``ch3`` / ``ch3-ablations`` / ``ch3-world-model`` / ``ch3-baselines`` / ``ch3-baselines-tabletop``
comparison presets of ``sb3-gcrl compare`` (MoReFree-SAC and its baselines and ablations, MoReFree (world model)
and reset-free PEG, IBC, MEDAL and R3L): each method is a plain RL-Zoo run of a section of
``zoo_configs/<algo>.yml`` (MoReFree-SAC: the env's section of ``sac.yml``, its baselines and ablations the variants
``<env id>@<method>``; what ``sb3-gcrl train --algo sac --env ... [--variant METHOD]`` runs), evaluated on RL-Zoo's
eval env, which has the same ``env_wrapper`` and stays episodic (start in rho_0, goal
from rho_g*, T_eval steps). This script only picks methods, budget and seeds, and adds the chapter's table:
per method the final success (mean of the last ``--final-evals`` evaluations; per seed), the mean over all
evaluations, and the task-relevant share of the replay buffer (Sec. 3.8: achieved goals within the env's success
radius of a sample of rho_0 or rho_g*) and how close the training data came to rho_g* (the nearest visited goal's
distance to a rho_g* sample, beside the success radius), both computed from the achieved goals ``sb3-gcrl compare``
keeps per run (``visited_goals.npy``, up to 20,000 evenly spaced over training). The comparison folder holds the
report, the curves and the Fig. 3.5-style heatmaps (``visitation_<env>.png``; Tabletop's shows the mug, as Fig. 3.9);
the table is also written to ``ch3_summary.csv``. For the world-model agents it also prints their probes over training
(distance vs shortest path, goal sensitivity, critic calibration: ``sb3_gcrl.morefree.diagnostics``, logged by the
PointUMaze CPU presets of ``morefree.yml`` every 10k steps), mean over seeds, and writes them to
``ch3_diagnostics.csv``.

Example (what docs/results.md quotes)::

    python scripts/reproduce_ch3.py --methods oracle morefree goexplore naive --seeds 0 1 2 --steps 100000 \\
        --eval-freq 10000 --eval-episodes 10 --final-evals 2 --out results/ch3_100k

Re-running resumes; ``--analyse-only`` re-reads ``--out``; ``--quick`` runs the ``ch3-quick`` preset.
"""

from __future__ import annotations

import argparse
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pandas as pd

from sb3_gcrl.compare.cli import _hyperparam
from sb3_gcrl.compare.presets import preset_labels, run_preset, select_methods
from sb3_gcrl.compare.run import RunSpec

#: where a run's log starts a new part: continued from a checkpoint at N steps, or from zero
PART = re.compile(r"^(?:Continuing the run from its checkpoint at (\d+) steps|The run starts from zero\b.*)$", re.M)
PRESETS = ("ch3", "ch3-ablations", "ch3-world-model", "ch3-baselines", "ch3-baselines-tabletop")


def task_goals(env_id: str, n: int = 256, seed: int = 0) -> tuple[np.ndarray, np.ndarray, float]:
    """Samples of rho_0 and of rho_g* that the env declares, and its success radius (the task-relevance radius)."""
    import gymnasium as gym

    from sb3_gcrl.goals import declared_task_goals

    env = gym.make(env_id)
    initial, evaluation = declared_task_goals(env, n, seed)
    env.close()
    return initial, evaluation, float(env.unwrapped.distance_threshold)


def first_success(run: pd.DataFrame) -> float:
    """Env steps of a run's first evaluation with any success (NaN when none succeeded)."""
    hits = run.loc[run["success_rate"] > 0, "timesteps"]
    return float(hits.min()) if len(hits) else np.nan


def run_specs(output: Path) -> list[RunSpec]:
    """The spec of every run under ``output`` (each run folder's own ``spec.json``: ``comparison.json`` lists only
    the runs of the last command, which may have trained a subset of the seeds or methods)."""
    from sb3_gcrl.compare.worker import SPEC_FILE

    return [RunSpec.from_dict(json.loads(path.read_text())) for path in sorted((output / "runs").rglob(SPEC_FILE))]


def chapter_table(output: Path, final_evals: int) -> pd.DataFrame:
    """One row per finished run: final success, mean success over all evaluations, best evaluation return, env steps
    of the first evaluation with a success, task-relevant share, closest visited goal to rho_g*."""
    from sb3_gcrl.callbacks.visitation import nearest_distances, task_relevant_fraction
    from sb3_gcrl.compare.storage import VISITED_FILE

    curves = pd.read_csv(output / "curves.csv")
    specs = run_specs(output)
    task = {env_id: task_goals(env_id) for env_id in curves["env"].unique()}
    rows = []
    for (env_id, method, seed), run in curves.groupby(["env", "method", "seed"], sort=False):
        success = run.sort_values("timesteps")["success_rate"].to_numpy()
        spec = next(s for s in specs if s.env_id == env_id and s.method == method and s.seed == seed)
        visited = output / "runs" / spec.relative_dir / VISITED_FILE
        share = closest = np.nan
        if visited.is_file():
            goals = np.load(visited).astype(np.float64)
            initial, evaluation, radius = task[env_id]
            share = task_relevant_fraction(goals, np.concatenate([initial, evaluation]), radius)
            closest = float(nearest_distances(goals, evaluation).min())
        rows.append(
            {
                "env": env_id,
                "method": method,
                "seed": int(seed),
                "final_success": float(np.mean(success[-final_evals:])),
                "mean_success": float(np.mean(success)),
                # steps spent in the goal zone per evaluation episode (reward 1 per step there): reaching the goal
                # without staying until the last step counts here, not in the success rate
                "max_mean_return": float(run["mean_return"].max()),
                "first_success_steps": first_success(run),
                "task_relevant_pct": 100 * share,
                # how near training came to the evaluation goals (compare with the success radius)
                "closest_to_goal": closest,
                "success_radius": task[env_id][2],
            }
        )
    return pd.DataFrame(rows)


def diagnostics_table(output: Path) -> pd.DataFrame:
    """The world-model agents' probes over training (``MoReFreeDiagnosticsCallback`` lines of each run's log):
    one row per run and probe."""
    from sb3_gcrl.compare.storage import LOG_FILE
    from sb3_gcrl.morefree.diagnostics import parse_diagnostics

    rows = []
    for spec in run_specs(output):
        log = output / "runs" / spec.relative_dir / LOG_FILE
        if not log.is_file():
            continue
        for step, figures in run_probes(log.read_text(errors="replace"), parse_diagnostics):
            rows.append({"env": spec.env_id, "method": spec.method, "seed": spec.seed, "timesteps": step, **figures})
    return pd.DataFrame(rows)


def run_probes(log: str, parse: Callable[[str], list[tuple[int, dict[str, float]]]]) -> list[tuple[int, dict]]:
    """The probes of one run's log, a run continued from checkpoints read as the uninterrupted run.

    A run's log holds each of its parts in turn: a part after ``Continuing the run from its checkpoint at N steps``
    replaces the probes after ``N`` of the parts before it, one after ``The run starts from zero`` all of them.
    Versions before the probe grid probed a continued run at its first step (``N + 1``, a repeat of the probe at
    ``N``: left out) and then one step off the grid (``N + 1 + k * diagnose_freq``: read at the grid step).
    """
    marks = list(PART.finditer(log))
    probes = parse(log[: marks[0].start()] if marks else log)
    for index, mark in enumerate(marks):
        end = marks[index + 1].start() if index + 1 < len(marks) else len(log)
        later = parse(log[mark.end() : end])
        resumed_at = int(mark.group(1)) if mark.group(1) else 0
        if resumed_at and later and later[0][0] == resumed_at + 1:
            later = [(step - 1, figures) for step, figures in later[1:]]
        probes = [(step, figures) for step, figures in probes if step <= resumed_at] + later
    return probes


def print_diagnostics(table: pd.DataFrame) -> None:
    """Mean over seeds of every probe, per method and env step (the world-model agents only)."""
    figures = [c for c in table.columns if c not in ("env", "method", "seed", "timesteps")]
    for (env_id, method), rows in table.groupby(["env", "method"], sort=False):
        print(f"{env_id} {method}: probes over training, mean over seeds (seeds probed)")
        print("| env steps | " + " | ".join(figures) + " | seeds |")
        print("|---" * (len(figures) + 2) + "|")
        for step, at in rows.groupby("timesteps"):
            print(f"| {step:,} | " + " | ".join(f"{at[f].mean():.2f}" for f in figures) + f" | {len(at)} |")


def print_table(table: pd.DataFrame) -> None:
    for (env_id, method), rows in table.groupby(["env", "method"], sort=False):
        finals, shares, closest = rows["final_success"], rows["task_relevant_pct"], rows["closest_to_goal"]
        share_text = (
            "not recorded (no visited_goals.npy: an on-policy agent, or a run from before sb3-gcrl compare kept them)"
            if shares.isna().all()
            else f"median {shares.median():.1f}% ({', '.join(f'{s:.1f}' for s in shares)})"
        )
        print(
            f"{env_id} {method:>20}: final success mean {finals.mean():.2f} median {finals.median():.2f} "
            f"(seeds: {', '.join(f'{f:.2f}' for f in finals)}); mean over all evaluations "
            f"{rows['mean_success'].mean():.2f}; best evaluation return (steps in the goal zone) "
            f"{', '.join(f'{r:.1f}' for r in rows['max_mean_return'])}; first success at "
            f"{first_successes(rows['first_success_steps'])} steps; task-relevant states {share_text}"
            + (
                ""
                if closest.isna().all()
                else f"; closest visited goal to rho_g* {', '.join(f'{c:.2f}' for c in closest)} "
                f"(success radius {rows['success_radius'].iloc[0]:g})"
            )
        )


def first_successes(steps: pd.Series) -> str:
    """Per-seed env steps of the first success, ``-`` for a seed without one."""
    return ", ".join("-" if np.isnan(value) else f"{value:,.0f}" for value in steps)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    labels = list(dict.fromkeys(label for name in PRESETS for label in preset_labels(name)))
    parser.add_argument(
        "--preset",
        choices=PRESETS,
        default="ch3",
        help="budget, seeds and default methods (ch3-world-model: the world-model agent vs reset-free PEG vs the "
        "MoReFree-SAC; ch3-baselines[-tabletop]: IBC, MEDAL and R3L beside those three on PointUMaze "
        "[Tabletop]); --methods may pick labels of any of these presets",
    )
    parser.add_argument("--methods", nargs="+", choices=labels, help="default: the preset's methods")
    parser.add_argument("--seeds", nargs="+", type=int, help="default: the preset's")
    parser.add_argument("--steps", type=int, help="env steps per run (default: the preset's)")
    parser.add_argument("--eval-freq", type=int, help="default: the preset's")
    parser.add_argument("--eval-episodes", type=int, help="default: the preset's")
    parser.add_argument("--final-evals", type=int, default=2, help="evaluations averaged into the final score")
    parser.add_argument("--workers", type=int, help="parallel runs (default: the number of cores)")
    parser.add_argument("--out", type=Path, default=Path("results/ch3"))
    parser.add_argument(
        "--params",
        nargs="+",
        type=_hyperparam,
        default=[],
        metavar="KEY:VALUE",
        help="hyperparameter overrides for every run, values in YAML (as sb3-gcrl compare --hyperparams)",
    )
    parser.add_argument("--analyse-only", action="store_true", help="only the table of the runs in --out")
    parser.add_argument("--quick", action="store_true", help="the ch3-quick preset (pipeline check)")
    args = parser.parse_args(argv)

    failed = False
    if not args.analyse_only:
        preset = "ch3-quick" if args.quick else args.preset
        # the chosen preset first: its spec wins where presets share a label (ibc on PointUMaze vs Tabletop)
        pool = [preset] if args.quick else [preset, *PRESETS]
        methods = select_methods(pool, args.methods or preset_labels(preset))
        result = run_preset(
            preset,
            args.out,
            methods=methods,
            seeds=args.seeds,
            n_timesteps=args.steps,
            eval_freq=args.eval_freq,
            n_eval_episodes=args.eval_episodes,
            n_workers=args.workers,
            final_window=args.final_evals,
            hyperparams=dict(args.params),
        )
        print(result.summary.table)
        failed = bool(result.summary.failed)
    if not (args.out / "curves.csv").is_file():
        print(f"no comparison in {args.out}", file=sys.stderr)
        return 1
    table = chapter_table(args.out, args.final_evals)
    if table.empty:
        print("no finished runs", file=sys.stderr)
        return 1
    table.to_csv(args.out / "ch3_summary.csv", index=False)
    print_table(table)
    probes = diagnostics_table(args.out)
    if not probes.empty:
        probes.to_csv(args.out / "ch3_diagnostics.csv", index=False)
        print_diagnostics(probes)
    print(f"wrote {args.out / 'ch3_summary.csv'}; report, curves and heatmaps in {args.out}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
