"""Reproduce the post-exploration ablation of thesis Ch. 6 (Fig. 6.3-6.6, Tables 6.2-6.3) via ``sb3-gcrl compare``.

Every run is a comparison run of ``zoo_configs/post_exploration_<task>_<variant>.yml`` (``off`` = no
post-exploration, ``on`` = Table 6.2/6.3 post-exploration, ``adaptive`` = our novelty-adaptive length): tabular
IMGEP (:class:`~sb3_gcrl.imgep.TabularIMGEP`, ``--algo imgep``) on FourRooms, LavaGap and LavaCrossing (presets
``ch6``, ``ch6-quick``), deep IMGEP (DDPG or SAC + HER with
:class:`~sb3_gcrl.post_exploration.PostExplorationWrapper`) on FetchReach and PointUMaze (preset ``ch6-deep``).
Settings come only from those files; this script picks tasks, variants, budget, seeds (and, for the lava tasks,
one layout per seed: the thesis's "environment seeds"; ``--epsilons`` repeats tabular runs with other exploration
rates, Table 6.2 averages epsilon in {0, 0.1, 0.3}).

The chapter's metric is the greedy success at reaching *every* goal (Sec. 6.5.1), which the episodic evaluation of
``sb3-gcrl compare`` (the env's own task) does not measure. The runs save their trained models, and this script
evaluates each final model with :func:`~sb3_gcrl.post_exploration.evaluate_all_goals`: tabular tasks over every
reachable cell, deep tasks over a fixed grid (FetchReach: 3x3x3 goals around the initial gripper position within
the target range; PointUMaze: 4 points in each free cell of the U, at most 150 steps per goal). Tabular models
also give the visitation entropy (Eq. 6.7), the coverage and the heatmaps (Fig. 6.4); for 2-D deep tasks the
comparison report draws the visitation heatmap with its entropy. Outputs in ``--out``: one comparison folder per
task (and layout / epsilon), ``ch6_results.json`` (one row per run), ``summary.md`` and ``heatmap_<task>.png``.

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

from sb3_gcrl.compare.presets import CH6_VARIANTS, config_methods, get_preset, run_preset

#: tabular tasks: env id and whether each seed gets its own layout
TABULAR_TASKS = {
    "FourRooms": ("GCRL/FourRoomsTabular-v0", False),
    "LavaGap": ("GCRL/LavaGapTabular-v0", True),
    "LavaCrossing": ("GCRL/LavaCrossingTabular-v0", True),
}
#: deep tasks: env id and the step cap per goal of the all-goals evaluation (None: the env's own time limit)
DEEP_TASKS = {"FetchReach": ("FetchReach-v4", None), "PointUMaze": ("GCRL/PointUMazeGoal-v0", 150)}


def deep_goal_grid(task: str, env: gym.Env) -> np.ndarray:
    """Fixed evaluation goals over the reachable goal space (see the module docstring)."""
    if task == "FetchReach":
        centre, r = env.unwrapped.initial_gripper_xpos, env.unwrapped.target_range
        axes = [np.linspace(c - r, c + r, 3) for c in centre]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    maze = env.unwrapped.maze
    offsets = np.array([[-0.25, -0.25], [-0.25, 0.25], [0.25, -0.25], [0.25, 0.25]])
    cells = [
        maze.cell_rowcol_to_xy(np.array([i, j]))
        for i, row in enumerate(maze.maze_map)
        for j, free in enumerate(row)
        if free == 0
    ]
    return np.concatenate([c + offsets for c in cells])


def _model_file(run_dir: Path) -> Path:
    files = sorted((run_dir / "zoo").glob("*/*/*.zip"))
    if not files:
        raise FileNotFoundError(f"no saved model in {run_dir / 'zoo'} (the run must be made with save_models)")
    return files[-1]


def evaluate_run(task: str, run_dir: Path, spec: dict[str, Any]) -> dict[str, Any]:
    """All-goals success of a finished run's saved model (+ entropy, coverage, visit counts for tabular tasks)."""
    from sb3_gcrl.imgep import TabularGoalEnv, TabularIMGEP
    from sb3_gcrl.post_exploration import evaluate_all_goals
    from sb3_gcrl.zoo_config import zoo_config_section

    row: dict[str, Any] = {
        "task": task,
        "variant": spec["method"],
        "seed": spec["seed"],
        "epsilon": spec["hyperparams"].get("epsilon"),
    }
    env_kwargs = spec["env_kwargs"]
    if task in TABULAR_TASKS:
        model = TabularIMGEP.load(_model_file(run_dir), env=gym.make(spec["env_id"], **env_kwargs))
        eval_env = TabularGoalEnv(gym.make(spec["env_id"], **env_kwargs))
        success = evaluate_all_goals(model, eval_env)
        counts = np.asarray(model.goal_space.counts)
        row.update(
            entropy=model.visitation_entropy(),
            coverage=model.coverage(),
            counts=counts.tolist(),
            width=int(eval_env.unwrapped.width),
        )
    else:
        from rl_zoo3.utils import ALGOS, get_wrapper_class

        # the eval env RL-Zoo builds from the run's config: its env_wrapper, left in episodic mode (only the
        # training env is switched to post-exploration by the callback); reset(options={"goal": g}) commands g
        section = zoo_config_section(Path(spec["config"]), spec["env_id"]) or {}
        wrap = get_wrapper_class(section)
        eval_env = gym.make(spec["env_id"], **env_kwargs)
        eval_env = wrap(eval_env) if wrap is not None else eval_env
        model = ALGOS[spec["algo"]].load(_model_file(run_dir), env=eval_env, device="cpu")
        goals = deep_goal_grid(task, eval_env)
        success = evaluate_all_goals(model, eval_env, goals, max_steps=DEEP_TASKS[task][1])
    row["success_all_goals"] = float(success.mean())
    row["n_goals"] = int(success.size)
    return row


def run_task(task: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    """Run the comparisons of one task and evaluate every finished run."""
    if task in TABULAR_TASKS:
        env_id, layout_per_seed = TABULAR_TASKS[task]
        preset, pattern = ("ch6-quick" if args.quick else "ch6"), f"post_exploration_{task.lower()}_{{name}}"
    else:
        env_id, layout_per_seed = DEEP_TASKS[task][0], False
        preset, pattern = "ch6-deep", f"post_exploration_{task.lower()}_{args.algo}_{{name}}"
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
                methods=config_methods(args.algo if task in DEEP_TASKS else "imgep", pattern, tuple(args.variants)),
                envs=[env_id],
                seeds=group_seeds,
                n_timesteps=args.steps,
                eval_freq=args.eval_freq,
                n_workers=args.workers,
                hyperparams={"epsilon": epsilon} if epsilon is not None else None,
                env_kwargs=env_kwargs,
                save_models=True,
                title=f"{task}: post-exploration {' vs '.join(args.variants)}",
            )
            for spec in result.specs:
                run_dir = folder / "runs" / spec.relative_dir
                if not any(s.relative_dir == spec.relative_dir for s, _, _ in result.summary.failed):
                    rows.append(evaluate_run(task, run_dir, spec.to_dict()))
                    print(f"{task:12s} {spec.method:8s} seed={spec.seed} eps={epsilon} "
                          f"all-goals success={rows[-1]['success_all_goals']:.3f}", flush=True)  # fmt: skip
    return rows


def summarise(rows: list[dict[str, Any]]) -> str:
    """Markdown table: final all-goals success (median, mean +- se), entropy and coverage per task and variant,
    and the paired differences (same seed, layout and epsilon) between variants."""
    lines = [
        "| task | variant | runs | success all goals: median | mean +- se | entropy (nats) median | coverage median |",
        "|---|---|---|---|---|---|---|",
    ]
    tasks = list(dict.fromkeys(row["task"] for row in rows))
    for task in tasks:
        for variant in CH6_VARIANTS:
            sel = [row for row in rows if row["task"] == task and row["variant"] == variant]
            if not sel:
                continue
            final = np.array([row["success_all_goals"] for row in sel])
            se = final.std(ddof=1) / np.sqrt(len(final)) if len(final) > 1 else 0.0
            entropy = np.median([row.get("entropy", np.nan) for row in sel])
            coverage = np.median([row.get("coverage", np.nan) for row in sel])
            lines.append(
                f"| {task} | {variant} | {len(sel)} | {np.median(final):.3f} | {final.mean():.3f} +- {se:.3f} | "
                f"{entropy:.3f} | {coverage:.3f} |"
            )
    lines += [
        "",
        "| task | comparison | pairs | final diff median | final wins | entropy diff median |",
        "|---|---|---|---|---|---|",
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
            d_final = np.array([a["success_all_goals"] - b["success_all_goals"] for a, b in pairs])
            d_entropy = np.array([a.get("entropy", np.nan) - b.get("entropy", np.nan) for a, b in pairs])
            lines.append(
                f"| {task} | {variant} - {reference} | {len(pairs)} | {np.median(d_final):+.3f} | "
                f"{int((d_final > 0).sum())}/{len(pairs)} | {np.median(d_entropy):+.3f} |"
            )
    return "\n".join(lines)


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
    plot_heatmaps(rows, args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
