"""Why pi_G does not hold its goal on reset-free PointUMaze: the goal's dead-end cell probed from a saved checkpoint.

At named places of the goal cell (the goal's centre, the corners, the back wall, the corridor), with the ball at rest
and the task's evaluation goal (the cell's centre), prints for a model saved by ``scripts/diagnose_morefree.py
--save`` (or ``MoReFree.save`` beside ``save_replay_buffer``):

* the learned distance ``D(place, g)`` and the critic ``V_G(place at rest, g)``;
* pi_G's own value under the world model from rest at each place (discounted ``-D`` over ``--steps`` imagined steps,
  no critic; deterministic and sampled actions): the ground truth the critic should rank as it does;
* pi_G's training objective from rest at each place against the zero action (do nothing), split into rewards and the
  slow critic's bootstrap (:func:`~sb3_gcrl.morefree.diagnostics.objective_gaps`);
* in the real env, where pi_G leaves the ball after 300 steps started at rest at each place;
* with ``--refit N``, a fresh V_G (``--refit-size`` units x layers) fitted alone for ``N`` updates on the frozen
  agent's imagination targets (its starts, goals and lambda-returns, a slow target every ``target_update_interval``
  updates): is a misranking the critic's size or lag, or its data?

::

    python scripts/diagnose_morefree.py --steps 30000 --every 10000 --save ckpt/mf_s0   # about 25 CPU-minutes
    python scripts/probe_goal_cell.py ckpt/mf_s0_30000.zip                             # about 15 s
    python scripts/probe_goal_cell.py ckpt/mf_s0_30000.zip --refit 1500 --refit-size 400 4
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import gymnasium as gym
import numpy as np
import torch as th

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.goals.task_goals import TaskRelevantGoals
from sb3_gcrl.morefree import MoReFree
from sb3_gcrl.morefree.diagnostics import objective_gaps
from sb3_gcrl.morefree.functional import symlog
from sb3_gcrl.morefree.losses import critic_loss
from sb3_gcrl.morefree.networks import Critic
from sb3_gcrl.morefree.policies import make_optimizer

#: places of the goal cell, as offsets from the goal's centre (the ball touches the back wall 0.4 from the centre)
PLACES = {
    "centre": (0.0, 0.0),
    "corner (-0.4, +0.4)": (-0.4, 0.4),
    "back wall (-0.4, 0)": (-0.4, 0.0),
    "corner (-0.4, -0.4)": (-0.4, -0.4),
    "corridor (+0.6, 0)": (0.6, 0.0),
}


def at_rest(points: np.ndarray) -> th.Tensor:
    """State vectors ``[x, y, vx = 0, vy = 0, x, y]`` of PointMaze balls at rest at ``points``."""
    return th.as_tensor(np.concatenate([points, np.zeros_like(points), points], 1), dtype=th.float32)


def model_values(model: MoReFree, states: th.Tensor, goals: th.Tensor, steps: int, deterministic: bool) -> np.ndarray:
    """pi_G's discounted return of ``-D`` over ``steps`` imagined steps from the memoryless latents of ``states``."""
    policy = model.policy
    latent = policy.hold_latent(states, deterministic=True)
    total, discount = th.zeros(len(states)), 1.0
    for _ in range(steps):
        action = policy.actor_g.act(latent.feat, goals, deterministic)[0]
        latent = policy.world_model.rssm.img_step(latent, action, deterministic)
        total += discount * -policy.distance(policy.world_model.decode_goal(latent.feat), goals)
        discount *= model.gamma
    return total.numpy()


def real_end(model: MoReFree, env: gym.Env, start: np.ndarray, goal: np.ndarray) -> tuple[np.ndarray, float]:
    """Where pi_G (as ``evaluate_policy`` acts) leaves the ball after 300 steps from rest at ``start``, and the share
    of those steps within the success radius."""
    obs, _ = env.reset(seed=0, options={"reset_pos": start, "goal": goal})
    inside, first = 0, np.array([True])
    for _ in range(300):
        action, _ = model.predict(obs, episode_start=first, deterministic=True)
        first = np.array([False])
        obs, _, _, _, info = env.step(action)
        inside += int(info["is_success"])
    return obs["achieved_goal"] - goal, inside / 300


def refit_critic(model: MoReFree, hidden: int, layers: int, updates: int, states: th.Tensor, goals: th.Tensor) -> None:
    """Fit a fresh V_G alone on the frozen agent's imagination targets; print its values at ``states`` 4 times."""
    policy, starts = model.policy, model.imagination_starts or model.batch_size * model.batch_length
    critic = Critic(policy.world_model.feat_dim, policy.goal_dim, hidden, layers)
    target = Critic(policy.world_model.feat_dim, policy.goal_dim, hidden, layers)
    target.load_state_dict(critic.state_dict())
    optimizer = make_optimizer(critic.parameters(), policy.learning_rates["critic_lr"], policy.weight_decay)
    rest = policy.hold_latent(states, deterministic=True).feat
    began = time.process_time()
    for update in range(1, updates + 1):
        with th.no_grad():
            batch = model.replay_buffer.sample(model.batch_size, model.batch_length, model._rng)
            _, post, _ = policy.world_model.loss(*(th.as_tensor(x) for x in batch))
            achieved = batch[0].reshape(-1, batch[0].shape[-1])[:, -policy.goal_dim :]
            rows = model._rng.choice(achieved.shape[0], starts, replace=False)
            start = post.flatten().rows(th.as_tensor(rows))
            imagined_goals = symlog(th.as_tensor(model.sample_imagination_goals(starts, achieved, achieved[rows])[0]))
            feats = model.imagine(start, imagined_goals)[0][:, :starts]
            rewards = model.goal_rewards(policy.world_model.decode_goal(feats), imagined_goals)
            returns = model.lambda_returns(feats, rewards, target, imagined_goals)
        loss = critic_loss(critic, feats, returns, imagined_goals, model.gamma)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        if update % model.target_update_interval == 0:
            target.load_state_dict(critic.state_dict())
        if update % max(1, updates // 4) == 0:
            with th.no_grad():
                values = critic(rest, goals).numpy()
            row = ", ".join(f"{name} {value:.2f}" for name, value in zip(PLACES, values, strict=True))
            print(f"refit {hidden} x {layers}, {update} updates ({time.process_time() - began:.0f} CPU-s): {row}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("model", help="saved model (.zip); its replay buffer <stem>_buffer.pkl beside it for --refit")
    parser.add_argument("--steps", type=int, default=300, help="imagined steps of the model's value")
    parser.add_argument("--paths", type=int, default=16, help="imagined paths per place for the sampled value")
    parser.add_argument("--refit", type=int, default=0, help="updates of a fresh V_G fitted alone (0: none)")
    parser.add_argument("--refit-size", type=int, nargs=2, default=(128, 2), metavar=("UNITS", "LAYERS"))
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    th.manual_seed(args.seed)
    th.set_num_threads(1)
    model = MoReFree.load(args.model, device="cpu")
    env = gym.make("GCRL/PointUMazeGoal-v0")
    base = env.unwrapped
    goal = base.maze.cell_rowcol_to_xy(np.array(base.goal_cell))  # the evaluation goals' centre
    points = goal + np.array(list(PLACES.values()))
    states, policy = at_rest(points), model.policy
    goals = symlog(th.as_tensor(goal, dtype=th.float32)).expand(len(points), -1)
    with th.no_grad():
        distance = policy.distance(symlog(th.as_tensor(points, dtype=th.float32)), goals).numpy()
        value = policy.critic_g(policy.hold_latent(states, deterministic=True).feat, goals).numpy()
        mode = model_values(model, states, goals, args.steps, True)
        paths = args.paths
        sampled = model_values(model, states.repeat(paths, 1), goals.repeat(paths, 1), args.steps, False)
        sampled = sampled.reshape(paths, len(points)).mean(0)
        gaps = objective_gaps(model, policy.hold_latent(states, deterministic=True), goals)
    print(f"goal {goal.round(2)}, {model.num_timesteps} env steps; the ball at rest at each place")
    print(
        "| place | D(place, g) | V_G | pi_G's value under the model, mode / sampled | objective vs do nothing "
        "(rewards, bootstrap) | real end after 300 steps (share inside) |"
    )
    print("|---|---|---|---|---|---|")
    for i, name in enumerate(PLACES):
        end, inside = real_end(model, env, points[i], goal)
        print(
            f"| {name} | {distance[i]:.3f} | {value[i]:.2f} | {mode[i]:.2f} / {sampled[i]:.2f} | "
            f"{gaps[0][i]:+.2f} ({gaps[1][i]:+.2f}, {gaps[2][i]:+.2f}) | {np.round(end, 2).tolist()} ({inside:.2f}) |"
        )
    if args.refit:
        model.load_replay_buffer(str(Path(args.model).with_suffix("")) + "_buffer.pkl")
        task_goals = TaskRelevantGoals(env, policy.goal_dim)
        model.task_goal_samples = lambda kind, n, rng=None: task_goals.sample(  # type: ignore[method-assign]
            kind, model._rng if rng is None else rng, n
        ).astype(np.float32)
        refit_critic(model, *args.refit_size, args.refit, states, goals)


if __name__ == "__main__":
    main()
