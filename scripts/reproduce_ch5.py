"""Reproduce thesis Ch. 5 (2M) at a CPU budget: WindyGrid (Fig. 5.5) and MinAtar (Fig. 5.6).

Subcommands (each run writes ``<out>/<task>/<agent>_seed<k>.npz``; ``report`` aggregates, prints tables and plots):

  python scripts/reproduce_ch5.py windygrid --seeds 0 1 2 3 4 --steps 100000 --out results/ch5
  python scripts/reproduce_ch5.py minatar --game Breakout --agent 2m --seed 0 --steps 100000 --out results/ch5
  python scripts/reproduce_ch5.py report --out results/ch5

WindyGrid agents: ``ec`` (TabularEpisodicControl), ``q`` (TabularQLearning), ``2m`` (TabularTwoMemory), with the
authors' tabular settings (REFERENCE.md). MinAtar agents: ``2m`` (TwoMemoryDQN), ``dqn`` (SB3 DQN, same network and
schedule), ``mfec`` (TwoMemoryDQN with p_ec = 1 and the Q-network never trained: pure MFEC acting, same code path).
Budgets are far below the thesis's (3M steps on MinAtar); the p_ec decay and epsilon schedule are scaled to the
budget by the same fractions as the authors' (tau = budget / 6, epsilon decays over the first 7% of training).
"""

from __future__ import annotations

import argparse
import glob
import os
import time
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from gymnasium.wrappers import TimeLimit
from stable_baselines3 import DQN
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

import sb3_gcrl  # noqa: F401  (registers GCRL/ and MinAtar envs)
from sb3_gcrl.envs.windy_grid import windy_grid_optimal_value
from sb3_gcrl.tabular import TabularEpisodicControl, TabularQLearning, TabularTwoMemory
from sb3_gcrl.two_memory import EPISODIC, MinAtarDQNPolicy, TwoMemoryDQN

WINDY_AGENTS = ("ec", "q", "2m")
MINATAR_AGENTS = ("2m", "dqn", "mfec")
MINATAR_MAX_STEPS = 10_000  # MinAtar registers no TimeLimit; this bounds a (rare) endless Breakout episode


def train_with_evaluation(
    model: BaseAlgorithm, eval_env: gym.Env, total_steps: int, eval_every: int, n_eval_episodes: int
) -> dict[str, np.ndarray]:
    """Learn in chunks of ``eval_every`` steps; after each, evaluate greedily (the 2M agent with its Eq. 5.6
    memory) and record the evaluation memory and the summed Q-values (tabular)."""
    steps, returns, eval_memory, q_sum, p_ec = [], [], [], [], []
    start = time.perf_counter()
    while model.num_timesteps < total_steps:
        model.learn(eval_every, reset_num_timesteps=False)
        mean_return, _ = evaluate_policy(model, eval_env, n_eval_episodes=n_eval_episodes, deterministic=True)
        steps.append(model.num_timesteps)
        returns.append(mean_return)
        has_dispatch = hasattr(model.policy, "evaluation_memory")
        eval_memory.append(model.policy.evaluation_memory() if has_dispatch else -1)
        p_ec.append(model.policy.last_p_ec if has_dispatch else np.nan)
        q_table = getattr(model, "q_table", None)
        q_sum.append(float(q_table.sum()) if q_table is not None else np.nan)
    return {
        "steps": np.array(steps),
        "returns": np.array(returns),
        "eval_memory": np.array(eval_memory),
        "q_sum": np.array(q_sum),
        "p_ec": np.array(p_ec),
        "wall_s": np.array(time.perf_counter() - start),
    }


def make_windy_agent(agent: str, seed: int, total_steps: int) -> BaseAlgorithm:
    env = Monitor(gym.make("GCRL/WindyGrid-v0"))
    common: dict[str, Any] = dict(seed=seed, exploration_fraction=0.5, exploration_initial_eps=0.1)
    # EC stores undiscounted returns here: with discounted max-returns, lucky wind gusts in different episodes can
    # make a greedy cycle look best (a loop costs too little), and greedy EC then loops until the time limit
    if agent == "ec":
        return TabularEpisodicControl(env=env, ec_gamma=1.0, **common)
    if agent == "q":
        return TabularQLearning(env=env, **common)
    schedule = {"type": "decayed", "start": 0.9, "end": 0.01, "decay": 20_000}
    return TabularTwoMemory(env=env, p_ec_schedule=schedule, ec_gamma=1.0, **common)


def run_windygrid(args: argparse.Namespace) -> None:
    os.makedirs(os.path.join(args.out, "windygrid"), exist_ok=True)
    for seed in args.seeds:
        for agent in args.agents:
            model = make_windy_agent(agent, seed, args.steps)
            eval_env = Monitor(gym.make("GCRL/WindyGrid-v0"))
            eval_env.reset(seed=10_000 + seed)
            result = train_with_evaluation(model, eval_env, args.steps, args.eval_every, args.eval_episodes)
            np.savez(os.path.join(args.out, "windygrid", f"{agent}_seed{seed}.npz"), **result)
            print(f"windygrid {agent} seed {seed}: final {result['returns'][-1]:.2f} ({float(result['wall_s']):.0f} s)")


def minatar_env(game: str, seed: int) -> gym.Env:
    env = Monitor(TimeLimit(gym.make(f"MinAtar/{game}-v1"), MINATAR_MAX_STEPS))
    env.reset(seed=seed)
    env.action_space.seed(seed)
    return env


def make_minatar_agent(agent: str, game: str, seed: int, total_steps: int) -> BaseAlgorithm:
    """The authors' MinAtar settings (REFERENCE.md) with schedules scaled to ``total_steps``."""
    dqn_kwargs: dict[str, Any] = dict(
        learning_rate=1e-4,
        buffer_size=50_000,
        learning_starts=1_000,
        batch_size=16,
        gamma=0.99,
        train_freq=10,
        gradient_steps=1,
        target_update_interval=2_000,
        exploration_fraction=0.07,
        exploration_initial_eps=0.1,
        exploration_final_eps=0.001,
        seed=seed,
        device="cpu",
    )
    optimizer = dict(optimizer_class=th.optim.RMSprop)
    env = minatar_env(game, seed)
    if agent == "dqn":
        return DQN(MinAtarDQNPolicy, env, policy_kwargs=optimizer, **dqn_kwargs)
    p_start, p_end = {"Breakout": (0.5, 0.1), "Asterix": (0.5, 0.1), "Seaquest": (0.5, 0.1)}.get(game, (0.9, 0.1))
    ec_kwargs = dict(ec_projection_dim=8, ec_n_neighbors=3, **optimizer)
    if agent == "mfec":
        # p_ec = 1: every episode is run by MFEC; the Q-network is never trained (learning_starts > budget)
        dqn_kwargs["learning_starts"] = total_steps + 1
        return TwoMemoryDQN("MinAtarPolicy", env, p_ec_schedule=1.0, policy_kwargs=ec_kwargs, **dqn_kwargs)
    schedule = {"type": "decayed", "start": p_start, "end": p_end, "decay": total_steps / 6}
    return TwoMemoryDQN("MinAtarPolicy", env, p_ec_schedule=schedule, policy_kwargs=ec_kwargs, **dqn_kwargs)


def run_minatar(args: argparse.Namespace) -> None:
    th.set_num_threads(1)
    os.makedirs(os.path.join(args.out, args.game), exist_ok=True)
    model = make_minatar_agent(args.agent, args.game, args.seed, args.steps)
    eval_env = minatar_env(args.game, 10_000 + args.seed)
    result = train_with_evaluation(model, eval_env, args.steps, args.eval_every, args.eval_episodes)
    np.savez(os.path.join(args.out, args.game, f"{args.agent}_seed{args.seed}.npz"), **result)
    final, wall = result["returns"][-1], float(result["wall_s"])
    print(f"{args.game} {args.agent} seed {args.seed}: final {final:.2f} ({wall:.0f} s)")


def _load(task_dir: str, agent: str) -> list[dict[str, np.ndarray]]:
    return [dict(np.load(path)) for path in sorted(glob.glob(os.path.join(task_dir, f"{agent}_seed*.npz")))]


def _summary_row(name: str, runs: list[dict[str, np.ndarray]], fractions: tuple[float, ...]) -> str:
    n = min(len(r["returns"]) for r in runs)
    curves = np.stack([r["returns"][:n] for r in runs])
    cells = []
    for fraction in fractions:
        i = max(int(round(fraction * n)) - 1, 0)
        cells.append(f"{np.median(curves[:, i]):8.2f} [{curves[:, i].min():7.2f},{curves[:, i].max():7.2f}]")
    early = np.median(curves[:, : max(int(0.3 * n), 1)].mean(axis=1))
    late = np.median(curves[:, -max(int(0.2 * n), 1) :].mean(axis=1))
    return f"{name:6s} " + " ".join(cells) + f"   early {early:7.2f}  late {late:7.2f}   (n={len(runs)})"


def report(args: argparse.Namespace) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fractions = (0.1, 0.25, 0.5, 1.0)
    for task_dir in sorted(glob.glob(os.path.join(args.out, "*"))):
        if not os.path.isdir(task_dir):
            continue
        task = os.path.basename(task_dir)
        agents = WINDY_AGENTS if task == "windygrid" else MINATAR_AGENTS
        results = {agent: _load(task_dir, agent) for agent in agents}
        results = {a: r for a, r in results.items() if r}
        if not results:
            continue
        steps = next(iter(results.values()))[0]["steps"]
        header = " ".join(f"{'@' + str(int(steps[max(int(round(f * len(steps))) - 1, 0)])):>25s}" for f in fractions)
        print(f"\n== {task}: evaluation return, median [min, max] over seeds ==")
        print("(early / late: median over seeds of the mean return over the first 30% / last 20% of training)")
        print(f"{'agent':6s} {header}")
        for agent, runs in results.items():
            print(_summary_row(agent, runs, fractions))
        if task == "windygrid":
            print(f"optimal expected return (value iteration): {windy_grid_optimal_value():.2f}")
        if "2m" in results:
            n = min(len(r["eval_memory"]) for r in results["2m"])
            ec_share = np.mean([r["eval_memory"][:n] == EPISODIC for r in results["2m"]], axis=0)
            print(
                "2M evaluation memory = EC (fraction of seeds) at "
                + ", ".join(
                    f"{int(steps[max(int(round(f * n)) - 1, 0)])}: {ec_share[max(int(round(f * n)) - 1, 0)]:.2f}"
                    for f in fractions
                )
            )
        n_panels = 2 if task == "windygrid" else 1
        fig, axes = plt.subplots(1, n_panels, figsize=(6 * n_panels, 4), squeeze=False)
        for agent, runs in results.items():
            n = min(len(r["returns"]) for r in runs)
            x = runs[0]["steps"][:n]
            curves = np.stack([r["returns"][:n] for r in runs])
            seeds = f"{len(runs)} seed" + ("s" if len(runs) > 1 else "")
            axes[0, 0].plot(x, np.median(curves, 0), label=f"{agent} ({seeds})")
            axes[0, 0].fill_between(x, curves.min(0), curves.max(0), alpha=0.2)
            if task == "windygrid" and agent in ("q", "2m"):
                q_sums = np.stack([r["q_sum"][:n] for r in runs])
                axes[0, 1].plot(x, np.median(q_sums, 0), label={"q": "RL", "2m": "2M-RL"}[agent])
                at = [max(int(round(f * n)) - 1, 0) for f in fractions]
                summary = ", ".join(f"{int(x[i])}: {np.median(q_sums[:, i]):.1f}" for i in at)
                print(f"summed Q ({agent}) median at {summary}")
        if task == "windygrid":
            axes[0, 0].axhline(windy_grid_optimal_value(), color="k", ls="--", label="optimum")
            axes[0, 1].set(title="summed Q-values", xlabel="env steps")
            axes[0, 1].legend()
        axes[0, 0].set(
            title=f"{task}: greedy evaluation return\n(median over seeds, band: min-max)",
            xlabel="env steps",
            ylabel="mean return",
        )
        axes[0, 0].legend()
        fig.tight_layout()
        fig.savefig(os.path.join(args.out, f"{task}.png"), dpi=100)
        plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    windy = sub.add_parser("windygrid")
    windy.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2, 3, 4])
    windy.add_argument("--agents", nargs="+", default=list(WINDY_AGENTS), choices=WINDY_AGENTS)
    windy.add_argument("--steps", type=int, default=100_000)
    windy.add_argument("--eval-every", type=int, default=2_000)
    windy.add_argument("--eval-episodes", type=int, default=20)
    minatar = sub.add_parser("minatar")
    minatar.add_argument("--game", default="Breakout")
    minatar.add_argument("--agent", choices=MINATAR_AGENTS, required=True)
    minatar.add_argument("--seed", type=int, default=0)
    minatar.add_argument("--steps", type=int, default=100_000)
    minatar.add_argument("--eval-every", type=int, default=5_000)
    minatar.add_argument("--eval-episodes", type=int, default=10)
    rep = sub.add_parser("report")
    for p in (windy, minatar, rep):
        p.add_argument("--out", default="results/ch5")
    args = parser.parse_args()
    {"windygrid": run_windygrid, "minatar": run_minatar, "report": report}[args.command](args)


if __name__ == "__main__":
    main()
