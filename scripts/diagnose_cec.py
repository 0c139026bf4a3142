"""Why CEC does or does not learn on a task: its memory against the geometry of the task's key space.

Trains CEC (thesis Ch. 4) with the env's section of ``zoo_configs/cec.yml`` for ``--steps`` env steps, then prints
a table of probes, each beside the quantity it must be compared with:

* memory: rows, rows per env step (1.0: every visited state made a new row, nothing was generalised), the share of
  rows whose value is positive (they lie on a path that reached the goal) and the largest value;
* key geometry, from ``--episodes`` greedy evaluation episodes: the distance from each visited key to its nearest
  stored row, and the distance a key moves in one env step, both against the distance threshold ``d`` (a state
  within ``d`` updates a row instead of adding one) and the vote radius ``n * d``, and the key dimensions that make
  most of a step's move; the share of visited states with a voting neighbour (a training step without one acts at
  random);
* the greedy policy's success and episode length.

Nothing is tuned here: the probes read the shipped settings. ``--normalize`` builds the keys from observations
standardised per dimension (SB3's ``VecNormalize``), to see whether the scale of the raw sensors is what sets the key
distance. Example (10-20 s on one core)::

    python scripts/diagnose_cec.py --env GCRL/PointGoal-v0 --steps 20000 --seed 0 [--normalize] \
        [--hyperparams projection_dim:None] [--env-kwargs heading_noise:0.1]
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.vec_env import VecNormalize

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl import CEC
from sb3_gcrl.zoo_config import parse_override, resolve_config


def build(
    env_id: str,
    seed: int,
    normalize: bool,
    overrides: dict[str, Any] | None = None,
    env_kwargs: dict[str, Any] | None = None,
) -> CEC:
    """CEC with the env's shipped section (budget and policy name left to the caller); with ``normalize``, on
    observations standardised by SB3's ``VecNormalize`` (running mean and std per dimension, as RL-Zoo's
    ``normalize`` setting), so that every key dimension moves on the same scale; ``env_kwargs`` go to the env."""
    section = {**resolve_config("cec", env_id).hyperparams, **(overrides or {})}
    section.pop("n_timesteps", None)
    policy = section.pop("policy", "CECPolicy")
    env = make_vec_env(env_id, n_envs=1, seed=seed, env_kwargs=env_kwargs)
    if normalize:
        env = VecNormalize(env, norm_obs=True, norm_reward=False)
    return CEC(policy, env, seed=seed, **section)


def greedy_episodes(
    model: CEC, env_id: str, episodes: int, seed: int, env_kwargs: dict[str, Any] | None = None
) -> tuple[list[np.ndarray], list[bool]]:
    """Keys of the states of ``episodes`` greedy episodes, and whether each reached the goal."""
    env = gym.make(env_id, **(env_kwargs or {}))
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        normalizer.training = False  # evaluation: the statistics stay as trained
    keys, successes = [], []
    for episode in range(episodes):
        obs, info = env.reset(seed=seed + 1000 + episode)
        trajectory = [obs]
        done = False
        while not done:
            action, _ = model.predict(obs if normalizer is None else normalizer.normalize_obs(obs), deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            trajectory.append(obs)
            done = terminated or truncated
        observations = np.stack(trajectory)
        if normalizer is not None:
            observations = normalizer.normalize_obs(observations)
        keys.append(model.policy.embedding(observations))
        successes.append(bool(info.get("is_success", False)))
    env.close()
    return keys, successes


def percentiles(values: np.ndarray) -> str:
    p10, p50, p90 = np.percentile(values, [10, 50, 90])
    return f"{p10:.3g} / {p50:.3g} / {p90:.3g}"


def probes(
    model: CEC, env_id: str, steps: int, episodes: int, seed: int, env_kwargs: dict[str, Any] | None = None
) -> dict[str, Any]:
    memory = model.policy.memory
    d, n = memory.distance_threshold, memory.filter_factor
    values = memory.values[: len(memory)]
    keys, successes = greedy_episodes(model, env_id, episodes, seed, env_kwargs)
    visited = np.concatenate(keys)
    nearest, _ = memory.index.search(visited, 1)
    steps_moved = np.concatenate([np.diff(k, axis=0) for k in keys])
    moves = np.linalg.norm(steps_moved, axis=1)
    share = (steps_moved**2).sum(axis=0) / max(float((steps_moved**2).sum()), 1e-12)
    top = np.argsort(share)[::-1][:3]
    lengths = [len(k) - 1 for k in keys]
    return {
        "memory rows": f"{len(memory)}",
        "rows per env step (1.0 = nothing generalised)": f"{len(memory) / steps:.3f}",
        "rows with a positive value (on a path to the goal)": f"{np.mean(values > 0):.3%}",
        "largest stored value": f"{values.max(initial=0.0):.3g}",
        "key dimension": f"{visited.shape[1]}",
        "distance threshold d / vote radius n*d": f"{d:.3g} / {n * d:.3g}",
        "distance to the nearest row, p10 / p50 / p90": percentiles(nearest[:, 0]),
        "key moved in one env step, p10 / p50 / p90": percentiles(moves),
        "key dimensions that make most of a step's move (share)": ", ".join(f"{i} ({share[i]:.0%})" for i in top),
        "visited states with a voting neighbour (within n*d)": f"{np.mean(nearest[:, 0] <= n * d):.1%}",
        "greedy success / mean episode length": f"{np.mean(successes):.2f} / {np.mean(lengths):.0f}",
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="GCRL/PointGoal-v0")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--episodes", type=int, default=5, help="greedy evaluation episodes probed")
    parser.add_argument("--normalize", action="store_true", help="keys from standardised observations (VecNormalize)")
    parser.add_argument(
        "--hyperparams",
        nargs="*",
        default=[],
        metavar="KEY:VALUE",
        help="settings over the shipped section, e.g. projection_dim:None (a probe of the key, not a tuning run)",
    )
    parser.add_argument(
        "--env-kwargs", nargs="*", default=[], metavar="KEY:VALUE", help="env constructor arguments (heading_noise:0.1)"
    )
    args = parser.parse_args()
    th.set_num_threads(1)
    overrides = dict(parse_override(item) for item in args.hyperparams)
    env_kwargs = dict(parse_override(item) for item in args.env_kwargs)
    start = time.perf_counter()
    model = build(args.env, args.seed, args.normalize, overrides, env_kwargs)
    model.learn(args.steps)
    table = probes(model, args.env, args.steps, args.episodes, args.seed, env_kwargs)
    keys = "standardised observations" if args.normalize else "raw observations"
    keys += "".join(f", {key}={value!r}" for key, value in {**overrides, **env_kwargs}.items())
    print(
        f"CEC on {args.env} ({keys}), seed {args.seed}, {args.steps} env steps ({time.perf_counter() - start:.0f} s)\n"
    )
    print("| probe | value |\n|---|---|")
    for name, value in table.items():
        print(f"| {name} | {value} |")


if __name__ == "__main__":
    main()
