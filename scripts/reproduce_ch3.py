"""Reproduce the reset-free PointUMaze comparison of thesis Ch. 3 (Fig. 3.4, Fig. 3.5) with model-free SAC+HER.

Every run is a plain RL-Zoo run of a config in ``zoo_configs/reset_free_pointumaze_<method>.yml``
(``python -m rl_zoo3.train --algo sac ...``), so what is measured is exactly what a user runs. The eval env is built
by RL-Zoo with the same ``env_wrapper`` as the train env and stays episodic (start in rho_0, goal from rho_g*,
T_eval steps); its ``evaluations.npz`` gives the success-rate curve. The replay buffer saved at the end gives the
task-relevant-state percentage and the visitation heatmap (Fig. 3.5 style).

Example (what the report quotes)::

    nice -n 10 python scripts/reproduce_ch3.py --methods oracle naive goexplore morefree --seeds 0 1 2 \
        --steps 30000 --workers 3 --out runs/ch3 --params batch_size:128 "policy_kwargs:dict(net_arch=[64, 64])"

Outputs in ``--out``: one RL-Zoo folder per run, ``summary.csv``, ``curves.png``, ``heatmaps.png`` and a printed
table (final success = mean of the last ``--final-evals`` evaluations; median and mean over seeds).
"""

from __future__ import annotations

import argparse
import csv
import os
import pickle
import subprocess
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import numpy as np

ENV_ID = "GCRL/PointUMazeGoal-v0"
METHODS = ("oracle", "naive", "goexplore", "morefree", "wo_bf", "wo_relabel", "alpha1")
REPO = Path(__file__).resolve().parents[1]
#: success radius of GCRL/PointUMazeGoal-v0, used as the task-relevance radius
TASK_RADIUS = 0.45
MAZE_LOW, MAZE_HIGH = [-1.5, -1.5], [1.5, 1.5]


def run_dir(out: Path, method: str, seed: int) -> Path:
    return out / method / f"seed{seed}"


def launch(
    out: Path, method: str, seed: int, steps: int, eval_freq: int, eval_episodes: int, params: list[str]
) -> tuple[str, int, float, int]:
    """Run one RL-Zoo training (skipped when its results already exist)."""
    folder = run_dir(out, method, seed)
    if list(folder.glob("sac/*/evaluations.npz")):
        return method, seed, 0.0, 0
    folder.mkdir(parents=True, exist_ok=True)
    cmd = [
        sys.executable, "-m", "rl_zoo3.train", "--algo", "sac", "--env", ENV_ID,
        "-conf", str(REPO / "zoo_configs" / f"reset_free_pointumaze_{method}.yml"),
        "--gym-packages", "sb3_gcrl", "-n", str(steps), "--seed", str(seed),
        "--eval-freq", str(eval_freq), "--eval-episodes", str(eval_episodes), "--num-threads", "1",
        "-f", str(folder), "--save-replay-buffer", "--verbose", "0",
    ] + (["-params", *params] if params else [])  # fmt: skip
    start = time.time()
    with open(folder / "train.log", "w") as log:
        rc = subprocess.call(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    return method, seed, time.time() - start, rc


def load_run(out: Path, method: str, seed: int, table_steps: int | None = None) -> dict | None:
    files = sorted(run_dir(out, method, seed).glob("sac/*/evaluations.npz"))
    if not files:
        return None
    data = np.load(files[-1])
    success = data["successes"].mean(axis=1) if data["successes"].size else np.zeros(len(data["timesteps"]))
    result = {"timesteps": data["timesteps"], "success": success}
    if table_steps is not None:
        keep = data["timesteps"] <= table_steps
        result["table_timesteps"], result["table_success"] = data["timesteps"][keep], success[keep]
    buffer_file = files[-1].parent / "replay_buffer.pkl"
    if buffer_file.exists():
        from sb3_gcrl.callbacks.visitation import task_relevant_fraction

        with open(buffer_file, "rb") as f:
            buffer = pickle.load(f)
        size = buffer.buffer_size if buffer.full else buffer.pos
        # transitions are stored in order (n_envs = 1): the first table_steps rows are the equal-budget data
        achieved = buffer.next_observations["achieved_goal"][:size].reshape(-1, 2).astype(np.float64)
        achieved = achieved[:table_steps] if table_steps is not None else achieved
        result["achieved"] = achieved
        result["task_relevant"] = task_relevant_fraction(achieved, task_goals(), TASK_RADIUS)
    return result


_TASK_GOALS: np.ndarray | None = None


def task_goals(n: int = 256) -> np.ndarray:
    """Samples of rho_0 and rho_g* declared by the env (the task-relevant regions)."""
    global _TASK_GOALS
    if _TASK_GOALS is None:
        import gymnasium as gym

        import sb3_gcrl  # noqa: F401 (registers the env)

        env = gym.make(ENV_ID).unwrapped
        rng = np.random.default_rng(0)
        goals = [env.sample_initial_goal(rng) for _ in range(n)] + [env.sample_evaluation_goal(rng) for _ in range(n)]
        _TASK_GOALS = np.asarray(goals)
    return _TASK_GOALS


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--methods", nargs="+", default=["oracle", "naive", "goexplore", "morefree"], choices=METHODS)
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    parser.add_argument("--steps", type=int, default=30_000)
    parser.add_argument("--eval-freq", type=int, default=5_000)
    parser.add_argument("--eval-episodes", type=int, default=10)
    parser.add_argument("--final-evals", type=int, default=2, help="evaluations averaged into the final score")
    parser.add_argument(
        "--table-steps",
        type=int,
        default=None,
        help="equal budget for the table: evaluations up to this step, first this many replay transitions "
        "(default: --steps; runs interrupted with SIGINT keep their saved buffer)",
    )
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--out", type=Path, default=Path("runs/ch3"))
    parser.add_argument("--analyse-only", action="store_true")
    parser.add_argument(
        "--params",
        nargs="*",
        default=[],
        help="RL-Zoo hyperparameter overrides for all runs, e.g. batch_size:128 'policy_kwargs:dict(net_arch=[64])'",
    )
    args = parser.parse_args(argv)

    if not args.analyse_only:
        jobs = [(m, s) for s in args.seeds for m in args.methods]
        with ThreadPoolExecutor(args.workers) as pool:
            futures = [
                pool.submit(launch, args.out, m, s, args.steps, args.eval_freq, args.eval_episodes, args.params)
                for m, s in jobs
            ]
            for future in futures:
                method, seed, seconds, rc = future.result()
                print(f"{method:>11} seed {seed}: {'done' if rc == 0 else f'FAILED rc={rc}'} in {seconds:.0f} s")

    rows, curves, heat = [], {}, {}
    for method in args.methods:
        finals, relevant = [], []
        for seed in args.seeds:
            run = load_run(args.out, method, seed, args.table_steps or args.steps)
            if run is None:
                continue
            if len(run["table_success"]) == 0:
                continue
            final = float(np.mean(run["table_success"][-args.final_evals :]))
            finals.append(final)
            curves.setdefault(method, []).append((run["timesteps"], run["success"]))
            if "task_relevant" in run:
                relevant.append(run["task_relevant"])
                heat.setdefault(method, run["achieved"])
            rows.append({"method": method, "seed": seed, "final_success": final,
                         "task_relevant_pct": 100 * run.get("task_relevant", np.nan)})  # fmt: skip
        if finals:
            print(
                f"{method:>11}: final success median {np.median(finals):.2f} mean {np.mean(finals):.2f} "
                f"(seeds: {', '.join(f'{f:.2f}' for f in finals)}); task-relevant states median "
                f"{100 * np.median(relevant):.1f}% ({', '.join(f'{100 * r:.1f}' for r in relevant)})"
            )
    if not rows:
        print("no finished runs")
        return 1
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "summary.csv", "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)
    plot(args.out, curves, heat)
    return 0


def plot(out: Path, curves: dict, heat: dict) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sb3_gcrl.callbacks.visitation import task_relevant_fraction, visitation_histogram

    fig, ax = plt.subplots(figsize=(5, 3.5))
    for method, runs in curves.items():
        length = min(len(t) for t, _ in runs)
        t = runs[0][0][:length]
        s = np.stack([s[:length] for _, s in runs])
        ax.plot(t, s.mean(0), label=f"{method} ({len(runs)} seeds)")
        ax.fill_between(t, s.min(0), s.max(0), alpha=0.15)
    ax.set_xlabel("env steps")
    ax.set_ylabel("episodic eval success")
    ax.set_title("Reset-free PointUMaze (SAC+HER)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "curves.png", dpi=120)
    plt.close(fig)

    if heat:
        fig, axes = plt.subplots(1, len(heat), figsize=(3.2 * len(heat), 3.2), squeeze=False)
        for ax, (method, achieved) in zip(axes[0], heat.items()):
            hist, xe, ye = visitation_histogram(achieved, MAZE_LOW, MAZE_HIGH, n_bins=30)
            ax.pcolormesh(xe, ye, np.log1p(hist.T), cmap="viridis")
            pct = 100 * task_relevant_fraction(achieved, task_goals(), TASK_RADIUS)
            ax.set_title(f"{method}: {pct:.1f}% task-relevant", fontsize=8)
            ax.set_aspect("equal")
        fig.tight_layout()
        fig.savefig(out / "heatmaps.png", dpi=120)
        plt.close(fig)
    print(f"wrote {out / 'summary.csv'}, {out / 'curves.png'}, {out / 'heatmaps.png'}")


if __name__ == "__main__":
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    sys.exit(main())
