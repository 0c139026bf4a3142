"""Raw random-action speed of the reset-free task suite (and of the stock envs they are built on).

Each env is stepped without resets (as in reset-free training) with pre-sampled uniform random actions; the
table shows the median steps/s over ``--repeats`` runs in one process (repeats interleaved over the envs). Usage::

    nice -n 10 python scripts/bench_reset_free_envs.py            # all envs, 2000 steps x 3 repeats
    python scripts/bench_reset_free_envs.py --steps 500 --ids GCRL/Tabletop-v0
    python scripts/bench_reset_free_envs.py --wall-stress 4000   # can the arm push the block out?
"""

from __future__ import annotations

import argparse
import importlib.util
import time

import gymnasium as gym
import numpy as np
import torch

import sb3_gcrl  # noqa: F401  (registers GCRL/ ids)
from sb3_gcrl.envs.tasks import RESET_FREE_ENV_IDS

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


def wall_stress(env_id: str, n_steps: int, seed: int = 0) -> tuple[int, int, float]:
    """A scripted arm shoves the block at a random wall (new direction every 100 steps, random fingers, bursts
    of random actions). Returns (steps with the block outside the walls, clamp firings, highest block z)."""
    env = gym.make(env_id).unwrapped
    rng = np.random.default_rng(seed)
    low, high = np.asarray(env.wall_low), np.asarray(env.wall_high)
    obs, _ = env.reset(seed=seed)
    outside, max_z, direction = 0, 0.0, np.zeros(2)
    for t in range(n_steps):
        if t % 100 == 0:
            direction = rng.normal(size=2)
            direction /= np.linalg.norm(direction)
        gripper, block = obs["observation"][:3], obs["achieved_goal"]
        behind = block[:2] - 0.05 * direction
        action = np.zeros(4)
        if t % 100 < 40 and np.linalg.norm(gripper[:2] - behind) > 0.02:  # get behind the block
            action[:2] = np.clip((behind - gripper[:2]) / 0.05, -1, 1)
            action[2] = np.clip((block[2] + 0.05 - gripper[2]) / 0.05, -1, 1)
        else:  # shove it towards the wall
            action[:2] = direction
            action[2] = np.clip((block[2] - gripper[2]) / 0.05, -1, 1)
        action[3] = rng.uniform(-1, 1)
        if t % 500 > 450:
            action = rng.uniform(-1, 1, size=4)
        obs, *_ = env.step(action)
        block = obs["achieved_goal"]
        outside += not (np.all(block[:2] >= low) and np.all(block[:2] <= high))
        max_z = max(max_z, float(block[2]))
    env.close()
    return outside, env.n_block_clamps, max_z


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=2000, help="steps per repeat (Tabletop runs 10x more)")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--ids", nargs="*", default=None, help="env ids (default: the whole suite + baselines)")
    parser.add_argument(
        "--wall-stress", type=int, default=0, metavar="STEPS", help="instead: shove the Fetch block at the walls"
    )
    args = parser.parse_args()
    torch.set_num_threads(1)

    if args.wall_stress:
        print(f"{'env':<42} {'steps outside':>14} {'clamp firings':>14} {'max block z':>12}")
        for env_id in [i for i in RESET_FREE_ENV_IDS if "Fetch" in i]:
            outside, clamps, max_z = wall_stress(env_id, args.wall_stress)
            print(f"{env_id:<42} {outside:>14} {clamps:>14} {max_z:>12.3f}")
        return

    if args.ids:
        targets = [(env_id, env_id, {}) for env_id in args.ids]
    else:
        targets = [(env_id, env_id, {}) for env_id in RESET_FREE_ENV_IDS] + BASELINES
    if importlib.util.find_spec("metaworld") is None:
        targets = [t for t in targets if t[1] != "GCRL/SawyerDoor-v0"]
        print("metaworld not installed: GCRL/SawyerDoor-v0 skipped")

    # Raw envs (no TimeLimit / checker wrappers). Repeats go round-robin over the envs, so that load changes on
    # a shared machine hit every env alike.
    envs = {label: gym.make(env_id, **kwargs).unwrapped for label, env_id, kwargs in targets}
    runs: dict[str, list[float]] = {label: [] for label in envs}
    for seed in range(args.repeats):
        for label, env in envs.items():
            n_steps = args.steps * (10 if "Tabletop" in label else 1)
            runs[label].append(steps_per_second(env, n_steps, seed))
    print(f"{'env':<42} {'median steps/s':>15} {'runs':>26}")
    for label, env in envs.items():
        env.close()
        print(f"{label:<42} {np.median(runs[label]):>15,.0f} {' '.join(f'{r:,.0f}' for r in runs[label]):>26}")


if __name__ == "__main__":
    main()
