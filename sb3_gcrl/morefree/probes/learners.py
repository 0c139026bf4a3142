"""Probes of the model-based MoReFree agent's learners, on posterior latents of its replayed states.

* :func:`goal_sensitivity`: mean absolute difference between pi_G's actions (the mode) in the same latent states
  under two different goals, as a fraction of the action range. An actor that ignores its goal scores 0; an
  untrained actor of the same architecture (:func:`untrained_goal_sensitivity`) scores the reference level.
* :func:`critic_calibration`: standard deviation of V_G over imagination starts divided by the standard deviation
  of their lambda-returns. About 1: the critic follows the returns it regresses; near 0: a flat critic whose
  bootstrap gives pi_G no long-horizon gradient.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch as th

from sb3_gcrl.morefree.functional import symlog
from sb3_gcrl.morefree.networks import Actor, LatentState

if TYPE_CHECKING:
    from sb3_gcrl.morefree.morefree import MoReFree


def _replay_latents(model: MoReFree, batch: int, rng: np.random.Generator) -> tuple[LatentState, th.Tensor]:
    """Posterior latents of a replayed batch (flat) and the achieved goals of the same rows (raw)."""
    policy = model.policy
    length = min(model.batch_length, max(2, int(model.replay_buffer.rows)))
    states, actions, is_first = (
        th.as_tensor(x, device=model.device) for x in model.replay_buffer.sample(batch, length, rng)
    )
    with th.no_grad():
        _, post, _ = policy.world_model.loss(states, actions, is_first)
    return post.flatten(), states[..., -policy.goal_dim :].reshape(-1, policy.goal_dim)


def goal_sensitivity(model: MoReFree, n_states: int = 512, seed: int = 0, actor: Actor | None = None) -> float:
    """Mean ``|pi_G(s, g_a) - pi_G(s, g_b)|`` of the deterministic actions, as a fraction of the action range.

    ``s`` are posterior latents of replayed states, ``g_a``, ``g_b`` two independent replayed achieved goals.

    :param model: the agent.
    :param n_states: latent states (rounded to whole replayed sequences).
    :param seed: seed of the draws.
    :param actor: the actor to probe (default the agent's pi_G; pass an untrained one for the reference level).
    :return: the sensitivity in [0, 1].
    """
    rng = np.random.default_rng(seed)
    latent, _ = _replay_latents(model, max(1, n_states // model.batch_length), rng)
    n = latent.deter.shape[0]
    goal_dim = model.policy.goal_dim
    goals = [
        symlog(th.as_tensor(model.replay_buffer.sample_states(n, rng)[:, -goal_dim:], device=model.device))
        for _ in range(2)
    ]
    actor = model.policy.actor_g if actor is None else actor
    with th.no_grad():
        a, b = (actor.act(latent.feat, g, deterministic=True)[0] for g in goals)
    return float((a - b).abs().mean().item() / 2.0)  # actions live in [-1, 1]


def untrained_goal_sensitivity(model: MoReFree, n_states: int = 512, seed: int = 0) -> float:
    """:func:`goal_sensitivity` of a freshly initialised actor of pi_G's architecture on the same latents."""
    policy = model.policy
    kwargs = policy.net_kwargs
    generator_state = th.random.get_rng_state()
    th.manual_seed(seed)
    try:
        actor = Actor(
            policy.world_model.feat_dim,
            policy.goal_dim,
            policy.action_space.shape[0],
            kwargs["head_hidden"],
            kwargs["head_layers"],
        ).to(model.device)
    finally:
        th.random.set_rng_state(generator_state)
    return goal_sensitivity(model, n_states, seed, actor)


def critic_calibration(
    model: MoReFree, n_starts: int = 512, seed: int = 0, goal_rng: np.random.Generator | None = None
) -> float:
    """``std(V_G(s_0, g)) / std(R^lambda_0)`` over imagination starts ``s_0`` and their lambda-returns.

    The starts are posterior latents of replayed states, the goals drawn as in training (Sec. 3.4.2); the returns
    come from pi_G imagined as in training, bootstrapped from the slow critic.

    :param model: the agent.
    :param n_starts: imagination starts (rounded to whole replayed sequences).
    :param seed: seed of the draws.
    :param goal_rng: generator of the imagination goals, drawn as in training (``None``: the agent's own).
    :return: the ratio (nan when the returns do not vary).
    """
    rng = np.random.default_rng(seed)
    policy = model.policy
    latent, achieved = _replay_latents(model, max(1, n_starts // model.batch_length), rng)
    achieved_np = achieved.cpu().numpy()
    goals_np = model.sample_imagination_goals(latent.deter.shape[0], achieved_np, achieved_np, goal_rng)[0]
    goals = symlog(th.as_tensor(goals_np, device=model.device))
    with th.no_grad():
        feats, _, _ = model.imagine(latent, goals)
        feats_g = feats[:, : goals.shape[0]]
        rewards = model.goal_rewards(policy.world_model.decode_goal(feats_g), goals)
        returns = model.lambda_returns(feats_g, rewards, policy.critic_g_target, goals)
        values = policy.critic_g(feats_g[0], goals)
    spread = returns[0].std().item()
    return float(values.std().item() / spread) if spread > 0 else float("nan")
