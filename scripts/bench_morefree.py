"""Speed of the model-based MoReFree agent on reset-free PointUMaze (CPU preset by default), one thread.

Prints env steps/s of data collection (world-model filtering + pi_G/pi_E actions, Back-and-Forth Go-Explore with
PEG goals), training steps/s (world model + ensemble + pi_G/distance + pi_E in imagination), and the time a
50k-step run would take at the preset's train ratio::

    python scripts/bench_morefree.py                      # CPU preset, 1 thread
    python scripts/bench_morefree.py --preset thesis --device cuda
"""

from __future__ import annotations

import argparse
import time

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--preset", choices=sorted(PRESETS), default="cpu")
    parser.add_argument("--device", default="cpu")
    parser.add_argument("--num-threads", type=int, default=1)
    parser.add_argument("--steps", type=int, default=2000, help="env steps timed (collection)")
    parser.add_argument("--train-steps", type=int, default=50, help="training steps timed")
    parser.add_argument("--repeats", type=int, default=3, help="repeats; medians are reported")
    args = parser.parse_args()
    th.set_num_threads(args.num_threads)
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
