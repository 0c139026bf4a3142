"""Overhead of the reset-free wrappers: env steps/s of the raw env vs the fully wrapped env (no learning).

Fully wrapped = ``ResetFreeWrapper`` + ``GoExploreWrapper`` with MoReFree's Back-and-Forth scheduler over
count-based novelty goals (Eq. 6.5, binned visited goals), in reset-free mode: every step records the achieved goal
in the goal space, recomputes the reward with ``compute_reward`` for the commanded goal, and runs the Go/Explore
phase logic. Raw and wrapped runs alternate in one process (so load changes hit both); medians are reported.
Rates are per second of this process's CPU time (``time.process_time``), which a loaded shared machine distorts
far less than wall time.

A third env gives the floor any Python wrapper reaches here: ``MandatedWorkWrapper``, one layer doing only the work
the design requires per step (recompute the reward for a commanded goal with ``compute_reward``, return a new
observation dict with that goal), nothing else.

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


class MandatedWorkWrapper(gym.Wrapper):
    """Reference floor (not part of the library): one wrapper layer doing only the mandated per-step work."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self._compute_reward = env.unwrapped.compute_reward
        self._goal = np.zeros(env.observation_space["desired_goal"].shape)

    def step(self, action: np.ndarray) -> tuple:
        obs, _, terminated, truncated, info = self.env.step(action)
        reward = float(self._compute_reward(obs["achieved_goal"], self._goal, info))
        obs = dict(obs)
        obs["desired_goal"] = self._goal.copy()
        return obs, reward, terminated, truncated, info


def make_wrapped(
    env_id: str, eval_horizon: int, goal_low: list[float], goal_high: list[float], monitor: bool = False
) -> gym.Env:
    env = gym.make(env_id)
    env = ResetFreeWrapper(Monitor(env) if monitor else env, hard_reset_every=200_000, eval_horizon=eval_horizon)
    kwargs = {"alpha": 0.2, "goal_low": goal_low, "goal_high": goal_high, "n_bins": 12, "within_bin": "visited"}
    env = GoExploreWrapper(env, "back_and_forth", kwargs)  # eval_horizon read from the ResetFreeWrapper
    env.reset(seed=0)
    env.set_training_mode(True)
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
    """Seconds for ``n`` single-goal ``compute_reward`` calls: the one call per step the design requires."""
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
    parser.add_argument("--goal-low", type=float, nargs="+", default=[-1.5, -1.5], help="novelty bins' lower bound")
    parser.add_argument("--goal-high", type=float, nargs="+", default=[1.5, 1.5], help="novelty bins' upper bound")
    args = parser.parse_args(argv)

    raw = gym.make(args.env)
    envs = {
        "raw env": raw,
        # same env, inner time limit lifted as in reset-free training: reset-free states can cost the simulator
        # more (e.g. Fetch's arm pressing on the table), which is not the wrappers' cost
        "raw env, no resets": gym.make(args.env, max_episode_steps=200_000),
        "floor (one layer, mandated work)": MandatedWorkWrapper(gym.make(args.env)),
        "fully wrapped": make_wrapped(args.env, args.eval_horizon, args.goal_low, args.goal_high),
    }
    actions = np.random.default_rng(0).uniform(-1, 1, (args.steps, *raw.action_space.shape)).astype(np.float32)
    for env in envs.values():
        steps_per_second(env, actions[:1000])  # warm-up
    rates: dict[str, list[float]] = {name: [] for name in envs}
    reward_shares = []
    for _ in range(args.repeats):
        for name, env in envs.items():
            rates[name].append(steps_per_second(env, actions))
        # cost of the recomputed reward relative to one raw step
        reward_shares.append(compute_reward_seconds(raw, args.steps) * rates["raw env"][-1] / args.steps)

    def make_vec_wrapped() -> gym.Env:
        return make_wrapped(args.env, args.eval_horizon, args.goal_low, args.goal_high, monitor=True)

    vec_raw = DummyVecEnv([lambda: Monitor(gym.make(args.env))])
    vec_raw.seed(0)
    vec_wrapped = DummyVecEnv([make_vec_wrapped])
    vec_wrapped.env_method("set_training_mode", True)  # what ResetFreeCallback does for the training env
    vec_raw_rates, vec_wrapped_rates = [], []
    for _ in range(args.repeats):
        vec_raw_rates.append(vec_steps_per_second(vec_raw, actions))
        vec_wrapped_rates.append(vec_steps_per_second(vec_wrapped, actions))

    def overhead(rates_: list[float], reference: list[float]) -> str:
        ratios = np.array(rates_) / np.array(reference)
        per_repeat = ", ".join(f"{100 * (1 - r):.1f}" for r in ratios)
        return f"median {100 * (1 - np.median(ratios)):.1f}% (per repeat: {per_repeat})"

    print(f"env {args.env}, {args.steps} random-action steps x {args.repeats} alternating repeats (per CPU second)")
    for name, values in rates.items():
        print(f"{name:38s} median {np.median(values):8.0f} steps/s  ({', '.join(f'{r:.0f}' for r in values)})")
    print(f"overhead (1 - wrapped/raw steps/s): {overhead(rates['fully wrapped'], rates['raw env'])}")
    print(f"overhead vs the raw env without resets: {overhead(rates['fully wrapped'], rates['raw env, no resets'])}")
    print(f"floor overhead (1 - floor/raw): {overhead(rates['floor (one layer, mandated work)'], rates['raw env'])}")
    print(
        f"of which the mandated compute_reward call per step: median {100 * np.median(reward_shares):.1f}% "
        "of a raw step"
    )
    print(
        f"as SB3 steps it (Monitor + DummyVecEnv): raw median {np.median(vec_raw_rates):.0f} steps/s, wrapped "
        f"{np.median(vec_wrapped_rates):.0f} steps/s, overhead {overhead(vec_wrapped_rates, vec_raw_rates)}"
    )
    wrapped = envs["fully wrapped"]
    interventions = wrapped.get_wrapper_attr("interventions")
    print(f"wrapped env: {interventions} physical reset(s), goals commanded {wrapped.goal_counts}")


if __name__ == "__main__":
    main()
