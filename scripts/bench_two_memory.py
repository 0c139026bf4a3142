"""Training speed of TwoMemoryDQN vs SB3 DQN on MinAtar Breakout (same network, same training schedule).

Both agents use the authors' network (MinAtarCNN + Linear) and schedule (one update of batch 16 every 10 env steps,
RMSprop 1e-4, buffer 5e4). Runs are interleaved in one process (``--repeats`` rounds of: DQN, 2M, 2M with p_ec = 1)
and each is timed over ``--steps`` training env steps after its own warm-up; medians and the 2M/DQN ratio are
printed. ``torch.set_num_threads(1)``.

  nice -n 10 python scripts/bench_two_memory.py --steps 20000 --repeats 3
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
from stable_baselines3 import DQN

import sb3_gcrl  # noqa: F401  (registers MinAtar)
from sb3_gcrl.two_memory import MinAtarDQNPolicy, TwoMemoryDQN


def make(kind: str, seed: int, game: str) -> Any:
    env = gym.make(f"MinAtar/{game}-v1")
    kwargs: dict[str, Any] = dict(
        learning_rate=1e-4,
        buffer_size=50_000,
        learning_starts=1_000,
        batch_size=16,
        train_freq=10,
        target_update_interval=2_000,
        exploration_initial_eps=0.1,
        exploration_final_eps=0.001,
        exploration_fraction=0.07,
        seed=seed,
        device="cpu",
    )
    if kind == "dqn":
        return DQN(MinAtarDQNPolicy, env, policy_kwargs=dict(optimizer_class=th.optim.RMSprop), **kwargs)
    p_ec = 1.0 if kind == "2m_pec1" else {"type": "decayed", "start": 0.5, "end": 0.1, "decay": 500_000}
    policy_kwargs = dict(optimizer_class=th.optim.RMSprop, ec_projection_dim=8, ec_n_neighbors=3)
    return TwoMemoryDQN("MinAtarPolicy", env, p_ec_schedule=p_ec, policy_kwargs=policy_kwargs, **kwargs)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--game", default="Breakout")
    parser.add_argument("--steps", type=int, default=20_000)
    parser.add_argument("--warmup", type=int, default=2_000)
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    th.set_num_threads(1)
    kinds = ("dqn", "2m", "2m_pec1")
    rates: dict[str, list[float]] = {k: [] for k in kinds}
    for repeat in range(args.repeats):
        for kind in kinds:
            model = make(kind, seed=repeat, game=args.game)
            model.learn(args.warmup)
            start = time.perf_counter()
            model.learn(args.steps, reset_num_timesteps=False)
            rate = args.steps / (time.perf_counter() - start)
            rates[kind].append(rate)
            extra = ""
            if kind != "dqn":
                extra = f", MFEC rows {len(model.policy.mfec)}, EC episodes {model.policy.episode_counts[0]}"
                extra += f" of {model.policy.episode_counts.sum()}"
            print(f"repeat {repeat} {kind:8s} {rate:7.0f} env steps/s{extra}", flush=True)
    medians = {k: float(np.median(v)) for k, v in rates.items()}
    print(f"\n{args.game}, {args.steps} training steps after {args.warmup} warm-up, {args.repeats} repeats (median):")
    for kind in kinds:
        print(f"  {kind:8s} {medians[kind]:7.0f} env steps/s   ratio to DQN {medians[kind] / medians['dqn']:.2f}")


if __name__ == "__main__":
    main()
