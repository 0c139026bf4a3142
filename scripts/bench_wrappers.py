"""Overhead of the reset-free wrappers: env steps/s of the raw env vs the fully wrapped env (no learning).

Fully wrapped = ``ResetFreeWrapper`` + ``GoExploreWrapper`` with MoReFree's Back-and-Forth scheduler over
count-based novelty goals (Eq. 6.5, binned visited goals), in reset-free mode: every step records the achieved goal
in the goal space, recomputes the reward with ``compute_reward`` for the commanded goal, and runs the Go/Explore
phase logic. Raw and wrapped runs alternate in one process (so load changes hit both); medians are reported.
Rates are per second of this process's CPU time (``time.process_time``), which a loaded shared machine distorts
far less than wall time.

Two settings: the bare gymnasium env (the wrappers' own cost against the cheapest possible step) and the env as SB3
steps it during training (``Monitor`` inside, ``DummyVecEnv`` outside, as ``make_vec_env``/RL-Zoo build it).

    nice -n 10 python scripts/bench_wrappers.py --env GCRL/PointUMazeGoal-v0 --steps 20000 --repeats 5
"""

from __future__ import annotations

import argparse
import time

import gymnasium as gym
import numpy as np
from stable_baselines3.common.monitor import Monitor
from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv

import sb3_gcrl  # noqa: F401 (registers GCRL/ envs)
from sb3_gcrl.wrappers import GoExploreWrapper, ResetFreeWrapper


def make_wrapped(env_id: str, eval_horizon: int, monitor: bool = False) -> gym.Env:
    env = gym.make(env_id)
    env = ResetFreeWrapper(Monitor(env) if monitor else env, hard_reset_every=200_000, eval_horizon=eval_horizon)
    kwargs = {"alpha": 0.2, "goal_low": [-1.5, -1.5], "goal_high": [1.5, 1.5], "n_bins": 12, "within_bin": "visited"}
    env = GoExploreWrapper(env, "back_and_forth", kwargs, eval_horizon=eval_horizon)
    env.reset(seed=0)
    env.enable_reset_free()
    return env


def steps_per_second(env: gym.Env, actions: np.ndarray) -> float:
    env.reset(seed=0)
    start = time.process_time()
    for action in actions:
        _, _, terminated, truncated, _ = env.step(action)
        if terminated or truncated:
            env.reset()
    return len(actions) / (time.process_time() - start)


def vec_steps_per_second(env: VecEnv, actions: np.ndarray) -> float:
    env.reset()
    start = time.process_time()
    for action in actions:
        env.step(action[None])  # DummyVecEnv resets finished episodes itself
    return len(actions) / (time.process_time() - start)


def compute_reward_seconds(env: gym.Env, n: int) -> float:
    """Seconds for ``n`` single-goal ``compute_reward`` calls: the one call per step the issue mandates."""
    obs, _ = env.reset(seed=0)
    achieved, desired = obs["achieved_goal"], obs["desired_goal"]
    compute_reward = env.unwrapped.compute_reward
    start = time.process_time()
    for _ in range(n):
        float(compute_reward(achieved, desired, {}))
    return time.process_time() - start


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="GCRL/PointUMazeGoal-v0")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--eval-horizon", type=int, default=300)
    args = parser.parse_args(argv)

    raw = gym.make(args.env)
    wrapped = make_wrapped(args.env, args.eval_horizon)
    actions = np.random.default_rng(0).uniform(-1, 1, (args.steps, *raw.action_space.shape)).astype(np.float32)
    steps_per_second(raw, actions[:1000])  # warm-up
    steps_per_second(wrapped, actions[:1000])
    raw_rates, wrapped_rates, reward_shares = [], [], []
    for _ in range(args.repeats):
        raw_rates.append(steps_per_second(raw, actions))
        wrapped_rates.append(steps_per_second(wrapped, actions))
        # cost of the recomputed reward relative to one raw step
        reward_shares.append(compute_reward_seconds(raw, args.steps) * raw_rates[-1] / args.steps)
    vec_raw = DummyVecEnv([lambda: Monitor(gym.make(args.env))])
    vec_raw.seed(0)
    vec_wrapped = DummyVecEnv([lambda: make_wrapped(args.env, args.eval_horizon, monitor=True)])
    vec_wrapped.env_method("enable_reset_free")  # what ResetFreeCallback does for the training env
    vec_raw_rates, vec_wrapped_rates = [], []
    for _ in range(args.repeats):
        vec_raw_rates.append(vec_steps_per_second(vec_raw, actions))
        vec_wrapped_rates.append(vec_steps_per_second(vec_wrapped, actions))
    ratios = np.array(wrapped_rates) / np.array(raw_rates)
    vec_ratios = np.array(vec_wrapped_rates) / np.array(vec_raw_rates)
    print(f"env {args.env}, {args.steps} random-action steps x {args.repeats} alternating repeats")
    print(f"raw env:        median {np.median(raw_rates):8.0f} steps/s  ({', '.join(f'{r:.0f}' for r in raw_rates)})")
    print(
        f"fully wrapped:  median {np.median(wrapped_rates):8.0f} steps/s  "
        f"({', '.join(f'{r:.0f}' for r in wrapped_rates)})"
    )
    print(
        f"overhead (1 - wrapped/raw steps/s): median {100 * (1 - np.median(ratios)):.1f}% "
        f"(per repeat: {', '.join(f'{100 * (1 - r):.1f}' for r in ratios)})"
    )
    print(
        f"of which the mandated compute_reward call per step: median {100 * np.median(reward_shares):.1f}% "
        "of a raw step"
    )
    print(
        f"as SB3 steps it (Monitor + DummyVecEnv): raw median {np.median(vec_raw_rates):.0f} steps/s, wrapped "
        f"{np.median(vec_wrapped_rates):.0f} steps/s, overhead median {100 * (1 - np.median(vec_ratios)):.1f}% "
        f"(per repeat: {', '.join(f'{100 * (1 - r):.1f}' for r in vec_ratios)})"
    )
    interventions = wrapped.get_wrapper_attr("interventions")
    print(f"wrapped env: {interventions} physical reset(s), goals commanded {wrapped.goal_counts}")


if __name__ == "__main__":
    main()
