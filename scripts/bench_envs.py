"""Raw random-action speed of every registered GCRL env and the MinAtar games (one process).

Each env is stepped with pre-sampled random actions through the full ``gym.make`` stack (resetting on
episode end); the table shows the median of ``--repeats`` timings, in env steps per second. For
reference, the MiniGrid rows also time the same task as plain ``gym.make("MiniGrid-...")`` with its image
observation, and PointUMaze is compared with gymnasium-robotics' ``PointMaze_UMaze-v3``.

Usage::

    nice -n 10 python scripts/bench_envs.py [--steps 20000] [--repeats 3] [--ids GCRL/WindyGrid-v0 ...]
"""

from __future__ import annotations

import argparse
import statistics
import time
import warnings

import gymnasium as gym
import numpy as np

import sb3_gcrl  # noqa: F401  (registers the envs)
from sb3_gcrl.envs import GCRL_ENV_IDS, MINATAR_ENV_IDS

REFERENCE_IDS = {
    "GCRL/PointUMaze-v0": "PointMaze_UMaze-v3",
    "GCRL/FourRoomsTabular-v0": "MiniGrid-FourRooms-v0",
    "GCRL/LavaCrossingTabular-v0": "MiniGrid-LavaCrossingS9N1-v0",
    "GCRL/LavaGapTabular-v0": "MiniGrid-LavaGapS7-v0",
}


def steps_per_second(env_id: str, n_steps: int, repeats: int, seed: int = 0) -> float:
    """Median over ``repeats`` of ``n_steps`` random-action steps per second (resets included)."""
    env = gym.make(env_id)
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(n_steps)]
    timings = []
    for repeat in range(repeats):
        env.reset(seed=seed + repeat)
        start = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        timings.append(n_steps / (time.perf_counter() - start))
    env.close()
    return statistics.median(timings)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--steps", type=int, default=20_000, help="steps per timing")
    parser.add_argument("--repeats", type=int, default=3, help="timings per env (the median is shown)")
    parser.add_argument("--ids", nargs="*", default=None, help="env ids (default: all GCRL ids + MinAtar)")
    args = parser.parse_args()
    warnings.filterwarnings("ignore")
    np.random.seed(0)

    env_ids = args.ids or list(GCRL_ENV_IDS + MINATAR_ENV_IDS)
    print(f"random actions, {args.steps} steps x {args.repeats} repeats, median steps/s, one process")
    print(f"{'env id':<40} {'obs space':<28} {'steps/s':>10}   reference")
    for env_id in env_ids:
        space = gym.make(env_id).observation_space
        space_text = type(space).__name__ + (f"({space.n})" if hasattr(space, "n") else str(space.shape or ""))
        speed = steps_per_second(env_id, args.steps, args.repeats)
        reference = ""
        if env_id in REFERENCE_IDS:
            ref_speed = steps_per_second(REFERENCE_IDS[env_id], args.steps, args.repeats)
            reference = f"{REFERENCE_IDS[env_id]}: {ref_speed:,.0f}"
        print(f"{env_id:<40} {space_text:<28} {speed:>10,.0f}   {reference}", flush=True)


if __name__ == "__main__":
    main()
