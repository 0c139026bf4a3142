"""Why MoReFree (world model) learns, or does not: its pieces probed against PointUMaze's true geometry.

Trains the CPU preset on reset-free PointUMaze (the ``GCRL/PointUMazeGoal-v0`` section of
``zoo_configs/morefree.yml``: its wrappers and settings) for ``--steps`` env steps, probing every ``--every`` steps, or
loads a saved model (``--load``, with its replay buffer from ``--load-buffer``, since the probes read replayed states),
and prints a table:

* distance rank correlation: Spearman correlation of the learned distance ``D(s, g)`` with the shortest-path
  distance through the maze, over replayed states ``s`` and replayed goals ``g`` (and, ``task``, the evaluation
  goals rho_g*);
* goal sensitivity: mean ``|pi_G(s, g_a) - pi_G(s, g_b)|`` (deterministic actions, fraction of the action range)
  over replayed latent states and two replayed goals, beside that of an untrained actor on the same states;
* critic calibration: ``std V_G / std R^lambda`` over imagination starts;
* distance minimum error: how far from the goal D puts its minimum, beyond the replayed state nearest to it;
* on ``--episodes`` evaluation episodes (deterministic pi_G, the task's own 300-step episodes): the real success,
  the share that reach the goal at some step and how long they stay there, the final path distance to the goal,
  beside the world model's prediction of the same episodes (imagined success, the share of episodes only the model
  thinks a success, the model's error ``imagination_horizon`` steps ahead along pi_G's path) and the learned
  distance's rank correlation along those paths (``sb3_gcrl.morefree.diagnostics.evaluation_rollouts``);

with wall / CPU time::

    python scripts/diagnose_morefree.py --steps 50000 --every 10000          # about 1 h on one core
    python scripts/diagnose_morefree.py --load run.zip --load-buffer run_buffer.pkl

``--variant`` picks a variant of that section (e.g. ``peg``: reset-free PEG), ``--config`` another file (e.g.
``morefree_thesis``, the thesis's scale).
"""

from __future__ import annotations

import argparse
import ast
import time
from pathlib import Path

import gymnasium as gym
import torch as th
from rl_zoo3.utils import get_wrapper_class
from stable_baselines3.common.env_util import make_vec_env

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.morefree import MoReFree
from sb3_gcrl.morefree.diagnostics import diagnose
from sb3_gcrl.zoo_config import resolve_config

#: (column, figure of diagnose) of the printed table, after the env steps
COLUMNS = (
    ("D rank corr. (replay goals)", "distance_rank_correlation"),
    ("D rank corr. (rho_g*)", "distance_rank_correlation_task"),
    ("D minimum error", "distance_minimum_error"),
    ("goal sensitivity", "goal_sensitivity"),
    ("untrained", "goal_sensitivity_untrained"),
    ("critic calibration", "critic_calibration"),
    ("success", "rollout_success"),
    ("reached", "rollout_reached"),
    ("held", "rollout_held"),
    ("imagined success", "rollout_imagined_success"),
    ("optimism", "rollout_optimism"),
    ("final path distance", "rollout_final_distance"),
    ("imagined final path distance", "rollout_imagined_final_distance"),
    ("imagined ends inside walls", "rollout_imagined_outside"),
    ("model error at H", "rollout_model_error"),
    ("reconstruction error", "rollout_reconstruction_error"),
    ("D rank corr. on pi_G's paths", "rollout_distance_correlation"),
    ("the same near the goal", "rollout_distance_correlation_near"),
)


def row(model: MoReFree, env: gym.Env, rollout_envs: list[gym.Env], wall: float, cpu: float) -> str:
    figures = diagnose(model, env, rollout_envs=rollout_envs)
    cells = " | ".join(f"{figures[name]:.2f}" for _, name in COLUMNS)
    return f"| {model.num_timesteps} | {cells} | {time.perf_counter() - wall:.0f} | {time.process_time() - cpu:.0f} |"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="GCRL/PointUMazeGoal-v0", help="env (section of the config)")
    parser.add_argument("--variant", help="variant of the env's section, e.g. peg (reset-free PEG)")
    parser.add_argument("--config", help="config file or shipped name (default: zoo_configs/morefree.yml)")
    parser.add_argument("--steps", type=int, default=50_000, help="env steps to train")
    parser.add_argument("--every", type=int, default=10_000, help="env steps between probes")
    parser.add_argument("--episodes", type=int, default=10, help="evaluation episodes per probe")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--set", nargs="*", default=[], help="MoReFree arguments, e.g. distance_warmup=0")
    parser.add_argument("--load", help="probe this saved model instead of training")
    parser.add_argument("--load-buffer", help="its replay buffer (MoReFree.save_replay_buffer)")
    parser.add_argument(
        "--save", help="save the trained model (and its replay buffer beside it) at every probe, as SAVE_<steps>.zip"
    )
    parser.add_argument("--num-threads", type=int, default=1)
    args = parser.parse_args()
    th.set_num_threads(args.num_threads)
    if args.save is not None:
        Path(args.save).parent.mkdir(parents=True, exist_ok=True)

    env_id, hyperparams = args.env, resolve_config("morefree", args.env, args.variant, args.config).hyperparams
    vec_env = make_vec_env(env_id, n_envs=1, seed=args.seed, wrapper_class=get_wrapper_class(hyperparams))
    env = vec_env.envs[0]
    rollout_envs = [gym.make(env_id) for _ in range(args.episodes)]
    print("| env steps | " + " | ".join(column for column, _ in COLUMNS) + " | wall s | CPU s |")
    print("|---" * (len(COLUMNS) + 3) + "|")
    wall, cpu = time.perf_counter(), time.process_time()
    if args.load is not None:
        model = MoReFree.load(args.load, env=vec_env, device="cpu")
        if args.load_buffer is None:
            raise SystemExit("--load needs --load-buffer: the probes read the agent's replayed states")
        model.load_replay_buffer(args.load_buffer)
        print(row(model, env, rollout_envs, wall, cpu), flush=True)
        return
    skip = ("n_timesteps", "policy", "env_wrapper", "callback")
    kwargs = {k: v for k, v in hyperparams.items() if k not in skip}
    if isinstance(kwargs.get("policy_kwargs"), str):
        kwargs["policy_kwargs"] = eval(kwargs["policy_kwargs"])  # RL-Zoo's convention: a dict literal in a string
    kwargs.update({k: ast.literal_eval(v) for k, v in (item.split("=", 1) for item in args.set)})
    model = MoReFree("MultiInputPolicy", vec_env, seed=args.seed, device="cpu", **kwargs)
    callback = ResetFreeCallback()
    while model.num_timesteps < args.steps:
        model.learn(args.every, callback=callback, reset_num_timesteps=False)
        if model._n_updates > 0:
            print(row(model, env, rollout_envs, wall, cpu), flush=True)
        if args.save is not None:
            stem = f"{Path(args.save).with_suffix('')}_{model.num_timesteps}"
            model.save(stem + ".zip")
            model.save_replay_buffer(stem + "_buffer.pkl")


if __name__ == "__main__":
    main()
