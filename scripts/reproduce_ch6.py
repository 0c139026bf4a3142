"""Reproduce the post-exploration ablation of thesis Ch. 6 (Fig. 6.3-6.6, Tables 6.2-6.3) via ``sb3-gcrl compare``.

Every run is a comparison run of a section of ``zoo_configs/imgep.yml``, ``ddpg.yml`` or ``sac.yml`` (``off`` = no
post-exploration, ``on`` = Table 6.2/6.3 post-exploration: the variants ``<env id>@off`` / ``@on``, and
``@post_exploration_on`` / ``@post_exploration_off`` of ``sac.yml``; ``adaptive`` = our novelty-adaptive length, the
default section of ``imgep.yml`` and ``ddpg.yml``): tabular
IMGEP (:class:`~sb3_gcrl.imgep.TabularIMGEP`, ``--algo imgep``) on FourRooms, LavaGap and LavaCrossing (presets
``ch6``, ``ch6-quick``), deep IMGEP (DDPG or SAC + HER with
:class:`~sb3_gcrl.post_exploration.PostExplorationWrapper`) on FetchReach and PointUMaze (preset ``ch6-deep``).
Settings come only from those sections; this script picks tasks, variants, budget, seeds (and, for the lava tasks,
one layout per seed: the thesis's "environment seeds"; ``--epsilons`` repeats tabular runs with other exploration
rates, Table 6.2 averages epsilon in {0, 0.1, 0.3}).

The chapter's metric is the greedy success at reaching *every* goal (Sec. 6.5.1), which the episodic evaluation of
``sb3-gcrl compare`` (the env's own task) does not measure. Every config lists
:class:`~sb3_gcrl.post_exploration.AllGoalsEvalCallback`, which compare runs at each evaluation point and stores as
the run's ``all_goals.csv``: tabular tasks over every reachable cell, deep tasks over a fixed grid (FetchReach:
3x3x3 goals around the initial gripper position within the target range; PointUMaze: 4 points in each free cell of
the U, at most 150 steps per goal), with the visitation entropy (Eq. 6.7) and coverage of the training data (tabular:
reachable cells; deep: the bins of the post-exploration goal space). This script reads those files: curves over
training, final value and AUC (normalised area under the curve, as the compare report); tabular runs also save their
model, whose visit counts give the heatmaps (Fig. 6.4). Each comparison folder's report draws the same curves
(``all_goals.png``, ``all_goals_entropy.png``). Outputs in ``--out``: one comparison folder per task (and layout /
epsilon), ``ch6_results.json`` (one row per run), ``summary.md``, ``curves.png`` (all-goals success, Fig. 6.3 /
6.5), ``entropy.png`` (visitation entropy over training) and ``heatmap_<task>.png``.

Examples (docs/results.md)::

    python scripts/reproduce_ch6.py --tasks FourRooms --seeds 5 --steps 100000 --eval-freq 10000 --out results/ch6
    python scripts/reproduce_ch6.py --tasks FetchReach --seeds 5 --steps 10000 --eval-freq 2000 --out results/ch6_deep

Re-running resumes; ``--from-json`` re-summarises ``--out``; ``--quick`` runs the ``ch6-quick`` preset.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pandas as pd

from sb3_gcrl.analysis.curves import aggregate_curves
from sb3_gcrl.analysis.plots import plot_learning_curves
from sb3_gcrl.analysis.statistics import run_scores
from sb3_gcrl.compare.presets import CH6_VARIANTS, get_preset, run_preset, variant_methods
from sb3_gcrl.compare.report import ALL_GOALS_METRIC
from sb3_gcrl.compare.storage import ALL_GOALS_FILE

#: tabular tasks: env id and whether each seed gets its own layout
TABULAR_TASKS = {
    "FourRooms": ("GCRL/FourRoomsTabular-v0", False),
    "LavaGap": ("GCRL/LavaGapTabular-v0", True),
    "LavaCrossing": ("GCRL/LavaCrossingTabular-v0", True),
}
#: deep tasks: env id (their goal grids are named in the configs' AllGoalsEvalCallback)
DEEP_TASKS = {"FetchReach": "FetchReach-v4", "PointUMaze": "GCRL/PointUMazeGoal-v0"}


def post_exploration_methods(algo: str, variants: list[str]) -> tuple[str, ...]:
    """Method specs of the post-exploration settings ``variants`` (``off``, ``on``, ``adaptive``) of ``algo``,
    labelled by setting: variants of ``imgep.yml`` / ``ddpg.yml`` (``adaptive``: their default section), or
    ``post_exploration_<setting>`` of ``sac.yml`` (which has no adaptive setting)."""
    if algo == "sac":
        return tuple(f"{variant}=sac@post_exploration_{variant}" for variant in variants)
    return variant_methods(algo, tuple(variants), default="adaptive")


def _model_file(run_dir: Path) -> Path:
    files = sorted((run_dir / "zoo").glob("*/*/*.zip"))
    if not files:
        raise FileNotFoundError(f"no saved model in {run_dir / 'zoo'} (the run must be made with save_models)")
    return files[-1]


def load_run(task: str, run_dir: Path, spec: dict[str, Any]) -> dict[str, Any]:
    """A finished run's all-goals curves (``all_goals.csv``) with their final values and AUC (+ visit counts of
    the saved model for tabular tasks)."""
    table = pd.read_csv(run_dir / ALL_GOALS_FILE)
    scores = run_scores(table.assign(env=task, method=spec["method"], seed=spec["seed"]), ALL_GOALS_METRIC)
    row: dict[str, Any] = {
        "task": task,
        "variant": spec["method"],
        "seed": spec["seed"],
        "epsilon": spec["hyperparams"].get("epsilon"),
        "timesteps": table["timesteps"].tolist(),
        "success": table[ALL_GOALS_METRIC].tolist(),
        "entropy_curve": table["visitation_entropy"].tolist(),
        "coverage_curve": table["coverage"].tolist(),
        "success_all_goals": float(scores["final"].iloc[0]),
        "auc": float(scores["auc"].iloc[0]),
        "entropy": float(table["visitation_entropy"].iloc[-1]),
        "coverage": float(table["coverage"].iloc[-1]),
        "n_goals": int(table["n_goals"].iloc[-1]),
    }
    if task in TABULAR_TASKS:
        from sb3_gcrl.imgep import TabularIMGEP

        env = gym.make(spec["env_id"], **spec["env_kwargs"])
        model = TabularIMGEP.load(_model_file(run_dir), env=env)
        row.update(counts=np.asarray(model.goal_space.counts).tolist(), width=int(env.unwrapped.width))
    return row


def run_task(task: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Run the comparisons of one task and evaluate every finished run."""
    if task in TABULAR_TASKS:
        env_id, layout_per_seed = TABULAR_TASKS[task]
        preset, algo = ("ch6-quick" if args.quick else "ch6"), "imgep"
    else:
        env_id, layout_per_seed = DEEP_TASKS[task], False
        preset, algo = "ch6-deep", args.algo
    seeds = list(range(args.seeds)) if args.seeds is not None else list(get_preset(preset).seeds)
    epsilons = args.epsilons if task in TABULAR_TASKS and args.epsilons else [None]
    # lava tasks: one comparison per layout seed (env kwargs hold for every run of a comparison)
    groups = [([seed], {"layout_seed": seed}, f"layout_{seed}") for seed in seeds] if layout_per_seed else []
    groups = groups or [(seeds, {}, "")]
    rows = []
    for epsilon in epsilons:
        for group_seeds, env_kwargs, name in groups:
            folder = args.out / task / (f"eps_{epsilon:g}" if epsilon is not None else "") / name
            result = run_preset(
                preset,
                folder,
                methods=post_exploration_methods(algo, args.variants),
                envs=[env_id],
                seeds=group_seeds,
                n_timesteps=args.steps,
                eval_freq=args.eval_freq,
                n_workers=args.workers,
                hyperparams={"epsilon": epsilon} if epsilon is not None else None,
                env_kwargs=env_kwargs,
                save_models=task in TABULAR_TASKS,  # their visit counts give the heatmaps
                title=f"{task}: post-exploration {' vs '.join(args.variants)}",
            )
            for spec in result.specs:
                run_dir = folder / "runs" / spec.relative_dir
                if not any(s.relative_dir == spec.relative_dir for s, _, _ in result.summary.failed):
                    rows.append(load_run(task, run_dir, spec.to_dict()))
                    print(f"{task:12s} {spec.method:8s} seed={spec.seed} eps={epsilon} "
                          f"all-goals success={rows[-1]['success_all_goals']:.3f} (AUC {rows[-1]['auc']:.3f})",
                          flush=True)  # fmt: skip
    return rows


def summarise(rows: list[dict[str, Any]]) -> str:
    """Markdown tables: final all-goals success (median, mean +- se), its AUC, final entropy and coverage per task and
    variant; the paired differences (same seed, layout and epsilon) between variants; a per-epsilon breakdown."""
    lines = [
        "| task | variant | runs | success all goals: median | mean +- se | AUC mean | entropy (nats) median | "
        "coverage median |",
        "|---|---|---|---|---|---|---|---|",
    ]
    tasks = list(dict.fromkeys(row["task"] for row in rows))
    for task in tasks:
        for variant in CH6_VARIANTS:
            sel = [row for row in rows if row["task"] == task and row["variant"] == variant]
            if not sel:
                continue
            final = np.array([row["success_all_goals"] for row in sel])
            se = final.std(ddof=1) / np.sqrt(len(final)) if len(final) > 1 else 0.0
            lines.append(
                f"| {task} | {variant} | {len(sel)} | {np.median(final):.3f} | {final.mean():.3f} +- {se:.3f} | "
                f"{np.mean([row['auc'] for row in sel]):.3f} | {np.median([row['entropy'] for row in sel]):.3f} | "
                f"{np.median([row['coverage'] for row in sel]):.3f} |"
            )
    lines += [
        "",
        "| task | comparison | pairs | AUC diff median | AUC wins | final diff median | entropy diff median | "
        "entropy wins |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for task in tasks:
        by_key = {(row["variant"], row["seed"], row["epsilon"]): row for row in rows if row["task"] == task}
        for variant, reference in (("on", "off"), ("adaptive", "off"), ("adaptive", "on")):
            pairs = [
                (row, by_key[(reference, seed, eps)])
                for (v, seed, eps), row in by_key.items()
                if v == variant and (reference, seed, eps) in by_key
            ]
            if not pairs:
                continue
            d_auc = np.array([a["auc"] - b["auc"] for a, b in pairs])
            d_final = np.array([a["success_all_goals"] - b["success_all_goals"] for a, b in pairs])
            d_entropy = np.array([a["entropy"] - b["entropy"] for a, b in pairs])
            lines.append(
                f"| {task} | {variant} - {reference} | {len(pairs)} | {np.median(d_auc):+.3f} | "
                f"{int((d_auc > 0).sum())}/{len(pairs)} | {np.median(d_final):+.3f} | {np.median(d_entropy):+.3f} | "
                f"{int((d_entropy > 0).sum())}/{len(pairs)} |"
            )
    epsilons = sorted({row["epsilon"] for row in rows if row["epsilon"] is not None})
    if len(epsilons) > 1:
        lines += ["", "| task | variant | " + " | ".join(f"eps={e:g}: final (AUC)" for e in epsilons) + " |"]
        lines.append("|---|---|" + "---|" * len(epsilons))
        for task in tasks:
            for variant in CH6_VARIANTS:
                cells = []
                for eps in epsilons:
                    sel = [r for r in rows if r["task"] == task and r["variant"] == variant and r["epsilon"] == eps]
                    if sel:
                        final = np.median([r["success_all_goals"] for r in sel])
                        cells.append(f"{final:.3f} ({np.mean([r['auc'] for r in sel]):.3f})")
                if cells:
                    lines.append(f"| {task} | {variant} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def plot_curves(rows: list[dict[str, Any]], out: Path) -> list[Path]:
    """All-goals success over training per task (Fig. 6.3 / 6.5: ``curves.png``) and, where every evaluation has
    one, the visitation entropy of the training data (``entropy.png``); mean over runs with a bootstrap band."""
    tidy = pd.concat(
        [
            pd.DataFrame(
                {
                    "env": row["task"],
                    "method": row["variant"],
                    "seed": f"{row['seed']}/{row['epsilon']}",  # one curve per run (seed, layout, epsilon)
                    "timesteps": row["timesteps"],
                    ALL_GOALS_METRIC: row["success"],
                    "visitation_entropy": row["entropy_curve"],
                }
            )
            for row in rows
        ],
        ignore_index=True,
    )
    written = []
    for metric, name in ((ALL_GOALS_METRIC, "curves.png"), ("visitation_entropy", "entropy.png")):
        counted = tidy.groupby("env")[metric].transform(lambda values: values.notna().all())
        if counted.any():
            plot_learning_curves(aggregate_curves(tidy[counted], metric), metric, path=out / name)
            written.append(out / name)
    return written


def plot_heatmaps(rows: list[dict[str, Any]], out: Path) -> None:
    """Fig. 6.4-style visitation heatmaps of the tabular tasks (seed 0, the smallest epsilon run)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    for task in dict.fromkeys(row["task"] for row in rows if "counts" in row):
        sel = [row for row in rows if row["task"] == task and row["seed"] == 0 and "counts" in row]
        epsilons = sorted({row["epsilon"] for row in sel}, key=lambda e: -1.0 if e is None else e)
        sel = [row for row in sel if row["epsilon"] == epsilons[0]]
        fig, axes = plt.subplots(1, len(sel), figsize=(4 * len(sel), 3.6), squeeze=False)
        for ax, row in zip(axes[0], sel):
            counts = np.array(row["counts"], dtype=float).reshape(-1, row["width"])
            image = ax.imshow(np.log1p(counts), cmap="viridis")
            ax.set_title(f"{task} {row['variant']}: log(1 + visits)")
            fig.colorbar(image, ax=ax, fraction=0.046)
        fig.tight_layout()
        fig.savefig(out / f"heatmap_{task}.png", dpi=120)
        plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--tasks", nargs="+", default=["FourRooms"], choices=[*TABULAR_TASKS, *DEEP_TASKS])
    parser.add_argument("--algo", default="ddpg", choices=["ddpg", "sac"], help="deep tasks only (sac: off/on)")
    parser.add_argument("--variants", nargs="+", default=list(CH6_VARIANTS), choices=list(CH6_VARIANTS))
    parser.add_argument("--seeds", type=int, help="number of seeds 0..N-1 (lava tasks: also the layout seeds)")
    parser.add_argument("--epsilons", type=float, nargs="+", help="tabular only (default: the config's 0.1)")
    parser.add_argument("--steps", type=int, help="env steps per run (default: the preset's)")
    parser.add_argument("--eval-freq", type=int, help="env steps between the compare evaluations")
    parser.add_argument("--workers", type=int, help="parallel runs (default: the number of cores)")
    parser.add_argument("--out", type=Path, default=Path("results/ch6"))
    parser.add_argument("--from-json", action="store_true", help="re-summarise and re-plot OUT/ch6_results.json")
    parser.add_argument("--quick", action="store_true", help="the ch6-quick preset (pipeline check)")
    args = parser.parse_args(argv)
    results = args.out / "ch6_results.json"
    if args.from_json:
        rows = json.loads(results.read_text())
    else:
        rows = [row for task in args.tasks for row in run_task(task, args)]
        args.out.mkdir(parents=True, exist_ok=True)
        results.write_text(json.dumps(rows))
    if not rows:
        print("no finished runs", file=sys.stderr)
        return 1
    table = summarise(rows)
    (args.out / "summary.md").write_text(table + "\n")
    print(table)
    plot_curves(rows, args.out)
    plot_heatmaps(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
