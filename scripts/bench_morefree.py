"""Speed of the model-based MoReFree agent on reset-free PointUMaze (CPU preset by default), one thread.

Prints env steps/s of data collection (world-model filtering + pi_G/pi_E actions, Back-and-Forth Go-Explore with
PEG goals), training steps/s (world model + ensemble + pi_G/distance + pi_E in imagination), and the time a
50k-step run would take at the preset's train ratio::

    python scripts/bench_morefree.py                      # CPU preset, 1 thread
    python scripts/bench_morefree.py --preset thesis --device cuda

``--curve growingtree`` / ``--curve pointumaze`` instead trains the CPU preset for ``--steps`` env steps (episodic
GrowingTree; reset-free PointUMaze as ``zoo_configs/morefree_pointumaze_morefree_cpu.yml`` sets it up, whose
``learning_starts`` then applies) and prints the deterministic evaluation success
every ``--eval-every`` steps (GrowingTree: goals -1, 0.5, 1, 1.5 from height 0; PointUMaze: the task's own
episodes of 300 steps), with wall and process CPU time::

    python scripts/bench_morefree.py --curve growingtree --steps 6000 --eval-every 1000
"""

from __future__ import annotations

import argparse
import ast
import time
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.morefree import CPU_NETWORK, THESIS_NETWORK, MoReFree, morefree_go_explore
from sb3_gcrl.wrappers import ResetFreeWrapper

#: algorithm settings of the two presets (networks: CPU_NETWORK / THESIS_NETWORK)
PRESETS = {
    "cpu": {"batch_size": 16, "batch_length": 32, "imagination_horizon": 15, "imagination_starts": 64},
    "thesis": {"batch_size": 50, "batch_length": 50, "imagination_horizon": 15, "imagination_starts": None},
}


def make_env(env: gym.Env) -> gym.Env:
    env = ResetFreeWrapper(env, hard_reset_every=200_000, eval_horizon=300)
    return morefree_go_explore(
        env, alpha=0.2, scheduler_kwargs={"goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 12}
    )


def evaluate(model: MoReFree, task: str, episodes: int) -> tuple[float, float]:
    """Deterministic pi_G (latent filtered across the episode): (success rate, mean final goal distance)."""
    if task == "growingtree":
        env = gym.make("GCRL/GrowingTreeGoal-v0")
        options = [{"goal": g} for g in (-1.0, 0.5, 1.0, 1.5)]
    else:
        env = gym.make("GCRL/PointUMazeGoal-v0")
        options = [None] * episodes
    successes, distances = [], []
    for k, option in enumerate(options):
        obs, _ = env.reset(seed=1000 + k, options=option)
        start, done, info = True, False, {}
        while not done:
            action, _ = model.predict(obs, episode_start=np.array([start]), deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            start, done = False, terminated or truncated
        successes.append(float(info["is_success"]))
        distances.append(float(np.linalg.norm(obs["achieved_goal"] - obs["desired_goal"])))
    return float(np.mean(successes)), float(np.mean(distances))


def curve(
    task: str,
    steps: int,
    eval_every: int,
    episodes: int,
    learning_starts: int,
    seed: int,
    overrides: dict[str, Any],
    save: str | None,
) -> None:
    """Train the CPU preset on ``task`` and print the evaluation every ``eval_every`` env steps."""
    algo = {"learning_starts": learning_starts, "train_ratio": 2, "policy_kwargs": dict(CPU_NETWORK), **PRESETS["cpu"]}
    if task == "growingtree":
        env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=seed)
        callback = None
    else:  # the shipped config: its wrappers and algorithm settings
        import yaml
        from rl_zoo3.utils import get_wrapper_class

        config = Path(__file__).resolve().parents[1] / "zoo_configs" / "morefree_pointumaze_morefree_cpu.yml"
        ((env_id, hyperparams),) = yaml.safe_load(config.read_text()).items()
        env = make_vec_env(env_id, n_envs=1, seed=seed, wrapper_class=get_wrapper_class(hyperparams))
        callback = ResetFreeCallback()
        skip = ("n_timesteps", "policy", "env_wrapper", "callback")
        algo = {k: v for k, v in hyperparams.items() if k not in skip}
        algo["policy_kwargs"] = eval(algo["policy_kwargs"])  # RL-Zoo's convention: a dict literal in a string
    model = MoReFree("MultiInputPolicy", env, seed=seed, device="cpu", **{**algo, **overrides})
    wall, cpu = time.perf_counter(), time.process_time()
    success, distance = evaluate(model, task, episodes)
    print(f"steps 0: success {success:.2f}, final distance {distance:.3f}", flush=True)
    while model.num_timesteps < steps:
        model.learn(eval_every, callback=callback, reset_num_timesteps=False)
        success, distance = evaluate(model, task, episodes)
        print(
            f"steps {model.num_timesteps}: success {success:.2f}, final distance {distance:.3f}, updates "
            f"{model._n_updates}, wall {time.perf_counter() - wall:.0f} s, CPU {time.process_time() - cpu:.0f} s",
            flush=True,
        )
    if save is not None:
        model.save(save)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--num-threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=2000, help="env steps timed (collection)")
    parser.add_argument("--train-steps", type=int, default=50, help="training steps timed")
    parser.add_argument("--repeats", type=int, default=3, help="repeats; medians are reported")
    parser.add_argument("--curve", choices=("growingtree", "pointumaze"), help="train and print a success curve")
    parser.add_argument("--eval-every", type=int, default=1000, help="--curve: env steps between evaluations")
    parser.add_argument("--episodes", type=int, default=5, help="--curve pointumaze: evaluation episodes")
    parser.add_argument("--learning-starts", type=int, default=1000, help="--curve: random prefill steps")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[], help="--curve: MoReFree arguments, e.g. distance_warmup=0")
    parser.add_argument("--save", help="--curve: save the trained model here")
    args = parser.parse_args()
    th.set_num_threads(args.num_threads)
    if args.curve is not None:
        overrides = {k: ast.literal_eval(v) for k, v in (item.split("=", 1) for item in args.set)}
        curve(
            args.curve,
            args.steps,
            args.eval_every,
            args.episodes,
            args.learning_starts,
            args.seed,
            overrides,
            args.save,
        )
        return
    network = CPU_NETWORK if args.preset == "cpu" else THESIS_NETWORK
    env = make_vec_env("GCRL/PointUMazeGoal-v0", n_envs=1, seed=0, wrapper_class=make_env)
    model = MoReFree(
        "MultiInputPolicy",
        env,
        learning_starts=500,
        train_ratio=2,
        policy_kwargs=dict(network),
        device=args.device,
        seed=0,
        **PRESETS[args.preset],
    )
    # prefill (random actions), then collection with the learned actors and PEG goals
    model.learning_starts = 500
    model.train_ratio = 10**9  # collection only while timing env steps
    model.learn(600, callback=ResetFreeCallback())
    env_rates, train_rates = [], []
    for _ in range(args.repeats):
        start = time.perf_counter()
        model.learn(args.steps, callback=ResetFreeCallback(), reset_num_timesteps=False)
        env_rates.append(args.steps / (time.perf_counter() - start))
        start = time.perf_counter()
        for _ in range(args.train_steps):
            model.train()
        if args.device != "cpu":
            th.cuda.synchronize()
        train_rates.append(args.train_steps / (time.perf_counter() - start))
    env_rate, train_rate = float(np.median(env_rates)), float(np.median(train_rates))
    ratio = 2
    hours = (50_000 / env_rate + 50_000 / ratio / train_rate) / 3600
    print(f"preset={args.preset} device={args.device} threads={args.num_threads} network={network}")
    print(f"env steps/s (collection, no training): {env_rate:.0f}  (runs: {[round(r) for r in env_rates]})")
    print(f"training steps/s: {train_rate:.2f}  (runs: {[round(r, 2) for r in train_rates]})")
    print(f"50k PointUMaze steps at train ratio {ratio}: {hours:.2f} h of this process")


if __name__ == "__main__":
    main()
