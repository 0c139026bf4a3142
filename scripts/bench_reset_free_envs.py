"""Raw random-action speed of the reset-free task suite (and of the stock envs they are built on).

Each env is stepped without resets (as in reset-free training) with pre-sampled uniform random actions; the
table shows the median steps/s over ``--repeats`` runs in one process. Usage::

    nice -n 10 python scripts/bench_reset_free_envs.py            # all envs, 2000 steps x 3 repeats
    python scripts/bench_reset_free_envs.py --steps 500 --ids GCRL/Tabletop-v0
"""

from __future__ import annotations

import argparse
import importlib.util
import time

import gymnasium as gym
import numpy as np
import torch

import sb3_gcrl  # noqa: F401  (registers GCRL/ ids)
from sb3_gcrl.envs.reset_free import RESET_FREE_ENV_IDS

# Stock envs the suite is built on, for comparison: (label, id, make kwargs).
BASELINES = [
    ("FetchPush-v4 (stock)", "FetchPush-v4", {}),
    ("FetchPickAndPlace-v4 (stock)", "FetchPickAndPlace-v4", {}),
    ("AntMaze_Open-v5 (stock, no cfrc)", "AntMaze_Open-v5", {"include_cfrc_ext_in_observation": False}),
]


def steps_per_second(env: gym.Env, n_steps: int, seed: int) -> float:
    """Step ``env`` ``n_steps`` times with pre-sampled random actions, resetting only on termination."""
    env.action_space.seed(seed)
    actions = np.stack([env.action_space.sample() for _ in range(n_steps)])
    env.reset(seed=seed)
    start = time.perf_counter()
    for action in actions:
        _, _, terminated, _, _ = env.step(action)
        if terminated:
            env.reset()
    return n_steps / (time.perf_counter() - start)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000, help="steps per repeat (Tabletop runs 10x more)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--ids", nargs="*", default=None, help="env ids (default: the whole suite + baselines)")
    args = parser.parse_args()
    torch.set_num_threads(1)

    if args.ids:
        targets = [(env_id, env_id, {}) for env_id in args.ids]
    else:
        targets = [(env_id, env_id, {}) for env_id in RESET_FREE_ENV_IDS] + BASELINES
    if importlib.util.find_spec("metaworld") is None:
        targets = [t for t in targets if t[1] != "GCRL/SawyerDoor-v0"]
        print("metaworld not installed: GCRL/SawyerDoor-v0 skipped")

    print(f"{'env':<42} {'median steps/s':>15} {'runs':>26}")
    for label, env_id, kwargs in targets:
        env = gym.make(env_id, **kwargs).unwrapped  # raw env: no TimeLimit / checker wrappers
        n_steps = args.steps * (10 if "Tabletop" in env_id else 1)
        runs = [steps_per_second(env, n_steps, seed) for seed in range(args.repeats)]
        env.close()
        print(f"{label:<42} {np.median(runs):>15,.0f} {' '.join(f'{r:,.0f}' for r in runs):>26}")


if __name__ == "__main__":
    main()
