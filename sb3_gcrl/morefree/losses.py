"""Losses of the model-based MoReFree agent (thesis Sec. 3.3.2), as pure functions of tensors and modules.

One training step of :class:`~sb3_gcrl.morefree.MoReFree` computes three of them, each a sum over learners whose
parameters are disjoint (one backward pass each):

* :func:`model_losses`: the world model's (reconstruction and balanced KL) and the Plan2Explore ensemble's, on the
  replayed sequences;
* :func:`imagination_losses`: the actors' of pi_G and pi_E, from one batch of imagination starts (:func:`imagine`),
  pi_G rewarded with ``-D`` (:func:`goal_rewards`), pi_E with the ensemble's disagreement; both learn by
  backpropagating lambda-returns (:func:`bootstrapped_returns`) through the model (DreamerV2's ``dynamics``
  gradient, :func:`actor_loss`);
* :func:`learner_losses`: the critics' (:func:`critic_loss`) and the dynamical distance's, on the detached
  imagined trajectories (and pairs of the replayed streams).
"""

from __future__ import annotations

from collections.abc import Callable

import torch as th
from torch import nn

from sb3_gcrl.morefree.functional import lambda_returns
from sb3_gcrl.morefree.networks import RSSM, Actor, DisagreementEnsemble, DynamicalDistance, LatentState, WorldModel
from sb3_gcrl.morefree.policies import MoReFreePolicy

#: (symlog earlier goals, symlog later goals, steps between them, 0/1 validity) of replayed pairs
ReplayPairs = tuple[th.Tensor, th.Tensor, th.Tensor, th.Tensor]


def along_path(goals: th.Tensor, steps: int) -> th.Tensor:
    """Goals ``(N, G)`` repeated for every step of imagined paths: ``(steps, N, G)`` (a view)."""
    return goals.unsqueeze(0).expand(steps, *goals.shape)


def imagine(
    rssm: RSSM, actor_g: Actor, actor_e: Actor, start: LatentState, goals: th.Tensor, horizon: int
) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """Roll pi_G (toward ``goals``) and pi_E from the same starts through the world model, in one batch.

    Rows ``[:N]`` of the outputs follow pi_G, rows ``[N:]`` pi_E; each step is one RSSM prior step for both.

    :param rssm: the world model's RSSM.
    :param actor_g: pi_G.
    :param actor_e: pi_E.
    :param start: flat imagination start states ``(N, ...)`` (detached).
    :param goals: symlog goals ``(N, G)`` of pi_G.
    :param horizon: imagined steps H.
    :return: features ``(H + 1, 2N, F)``, actions ``(H, 2N, A)`` (``actions[t]`` is taken in state ``t``),
        entropies ``(H, 2N)``.
    """
    n = goals.shape[0]
    latent = LatentState(*(th.cat([x, x]) for x in start))
    feats, actions, entropies = [latent.feat], [], []
    for _ in range(horizon):
        feat = latent.feat.detach()
        action_g, entropy_g = actor_g.act(feat[:n], goals)
        action_e, entropy_e = actor_e.act(feat[n:])
        action = th.cat([action_g, action_e])
        latent = rssm.img_step(latent, action)
        feats.append(latent.feat)
        actions.append(action)
        entropies.append(th.cat([entropy_g, entropy_e]))
    return th.stack(feats), th.stack(actions), th.stack(entropies)


def imagine_path(
    rssm: RSSM, start: LatentState, act: Callable[[th.Tensor], th.Tensor], horizon: int, mode: bool = False
) -> tuple[th.Tensor, th.Tensor]:
    """Roll one policy from ``start`` through the world model's prior.

    :param rssm: the world model's RSSM.
    :param start: flat start states ``(N, ...)``.
    :param act: the action ``(N, A)`` taken in latent features ``(N, F)``.
    :param horizon: imagined steps H.
    :param mode: step with the prior's mode instead of a sample.
    :return: features ``(H + 1, N, F)`` and actions ``(H, N, A)`` (``actions[t]`` is taken in state ``t``).
    """
    latent, feats, actions = start, [start.feat], []
    for _ in range(horizon):
        action = act(latent.feat)
        latent = rssm.img_step(latent, action, mode)
        feats.append(latent.feat)
        actions.append(action)
    return th.stack(feats), th.stack(actions)


def goal_rewards(distance: DynamicalDistance, achieved: th.Tensor, goals: th.Tensor) -> th.Tensor:
    """pi_G's reward ``-D(achieved goal of s_{t+1}, g)`` from the decoded achieved goals ``(H + 1, N, G)`` of an
    imagined path: ``(H, N)``.

    :param distance: the dynamical distance D.
    :param achieved: symlog achieved goals along the paths.
    :param goals: symlog goals ``(N, G)``.
    """
    return -distance(achieved[1:], along_path(goals, achieved.shape[0] - 1))


def bootstrapped_returns(
    feats: th.Tensor, rewards: th.Tensor, target: nn.Module, goals: th.Tensor | None, gamma: float, lambda_: float
) -> th.Tensor:
    """Lambda-returns ``(H, N)`` of imagined states ``feats (H + 1, N, F)``, bootstrapped from a slow critic.

    :param feats: latent features along the paths.
    :param rewards: ``(H, N)`` rewards.
    :param target: the slow critic.
    :param goals: symlog goals ``(N, G)`` of a goal-conditioned critic, else None.
    :param gamma: discount.
    :param lambda_: TD(lambda) parameter.
    """
    expand = None if goals is None else along_path(goals, feats.shape[0])
    return lambda_returns(rewards, target(feats, expand), gamma, lambda_)


def discounts(returns: th.Tensor, gamma: float) -> th.Tensor:
    """``gamma^t`` for the ``H`` steps of returns ``(H, N)``: ``(H, 1)``."""
    steps = returns.shape[0]
    return gamma ** th.arange(steps, device=returns.device, dtype=returns.dtype).unsqueeze(-1)


def actor_loss(returns: th.Tensor, entropies: th.Tensor, gamma: float, entropy_coef: float) -> th.Tensor:
    """DreamerV2's dynamics-backpropagation objective: discounted lambda-returns plus the entropy bonus."""
    return -(discounts(returns, gamma) * (returns + entropy_coef * entropies)).mean()


def critic_loss(
    critic: nn.Module, feats: th.Tensor, returns: th.Tensor, goals: th.Tensor | None, gamma: float
) -> th.Tensor:
    """Discounted regression of the critic on the (detached) lambda-returns of the imagined states."""
    expand = None if goals is None else along_path(goals, returns.shape[0])
    prediction = critic(feats[:-1].detach(), expand)
    return (discounts(returns, gamma) * (prediction - returns.detach()).pow(2)).mean()


def model_losses(
    world_model: WorldModel, ensemble: DisagreementEnsemble, states: th.Tensor, actions: th.Tensor, is_first: th.Tensor
) -> tuple[th.Tensor, LatentState, dict[str, th.Tensor]]:
    """World-model loss plus the Plan2Explore ensemble's on the same (detached) posteriors.

    The ensemble predicts the next stochastic state from (features, action), never across a stream start.

    :param world_model: the world model.
    :param ensemble: the Plan2Explore ensemble.
    :param states: replayed state vectors ``(T, B, S)``.
    :param actions: the actions before them ``(T, B, A)``.
    :param is_first: stream starts ``(T, B)``.
    :return: (summed loss, detached posteriors ``(T, B, ...)``, detached metrics).
    """
    wm_loss, post, metrics = world_model.loss(states, actions, is_first)
    feat = post.feat.detach()
    valid = (~is_first[1:]).to(feat.dtype)
    ensemble_loss = ensemble.loss(feat[:-1], actions[1:], post.stoch[1:].detach(), valid)
    metrics = {**metrics, "world_model_loss": wm_loss.detach(), "ensemble_loss": ensemble_loss.detach()}
    return wm_loss + ensemble_loss, post.detach(), metrics


def imagination_losses(
    policy: MoReFreePolicy,
    start: LatentState,
    goals: th.Tensor,
    horizon: int,
    gamma: float,
    lambda_: float,
    entropy_coef: float,
    expl_reward_scale: float,
) -> tuple[th.Tensor, tuple[th.Tensor, ...], dict[str, th.Tensor]]:
    """Actor losses of pi_G and pi_E from one batch of imagination starts (Sec. 3.3.2); runs with the world
    model, the distance and the ensemble frozen.

    pi_G is imagined from ``start`` toward ``goals`` with the reward ``-D``; pi_E from the same starts with the
    ensemble's disagreement; both learn by backpropagating lambda-returns through the model.

    :param policy: the agent's networks.
    :param start: imagination start states (flat batch, detached).
    :param goals: symlog goals of pi_G, one per start.
    :param horizon: imagined steps.
    :param gamma: discount.
    :param lambda_: TD(lambda) parameter.
    :param entropy_coef: actor entropy bonus.
    :param expl_reward_scale: scale of pi_E's disagreement reward.
    :return: (summed actor loss, detached (pi_G features, pi_E features, pi_G returns, pi_E returns, pi_G's
        decoded achieved goals), metrics).
    """
    n = goals.shape[0]
    feats, actions, entropies = imagine(policy.world_model.rssm, policy.actor_g, policy.actor_e, start, goals, horizon)
    feats_g, feats_e = feats[:, :n], feats[:, n:]
    achieved = policy.world_model.decode_goal(feats_g)
    rewards_g = goal_rewards(policy.distance, achieved, goals)
    rewards_e = expl_reward_scale * policy.ensemble.disagreement(feats_e[:-1], actions[:, n:])
    returns_g = bootstrapped_returns(feats_g, rewards_g, policy.critic_g_target, goals, gamma, lambda_)
    returns_e = bootstrapped_returns(feats_e, rewards_e, policy.critic_e_target, None, gamma, lambda_)
    actor_g_loss = actor_loss(returns_g, entropies[:, :n], gamma, entropy_coef)
    actor_e_loss = actor_loss(returns_e, entropies[:, n:], gamma, entropy_coef)
    metrics = {
        "actor_g_loss": actor_g_loss,
        "actor_e_loss": actor_e_loss,
        "imagined_return_g": returns_g.mean(),
        "imagined_return_e": returns_e.mean(),
        "imagined_reward_e": rewards_e.mean(),
        "action_g_abs": actions[:, :n].abs().mean(),
        "entropy_g": entropies[:, :n].mean(),
    }
    imagined = tuple(x.detach() for x in (feats_g, feats_e, returns_g, returns_e, achieved))
    return actor_g_loss + actor_e_loss, imagined, {k: v.detach() for k, v in metrics.items()}


def learner_losses(
    policy: MoReFreePolicy,
    imagined: tuple[th.Tensor, ...],
    goals: th.Tensor,
    groups: th.Tensor,
    replay_pairs: ReplayPairs | None,
    gamma: float,
    unit: int,
    n_pairs: int,
    neg_fraction: float,
) -> tuple[th.Tensor, dict[str, th.Tensor]]:
    """Critic losses of V_G and V_E and the distance's, from the imagined trajectories of
    :func:`imagination_losses`.

    D is trained on pairs of the imagined pi_G trajectories' decoded achieved goals (LEXA / PEG) and, with
    ``replay_pairs``, on pairs of achieved goals of the replayed streams, in one unit.

    :param policy: the agent's networks.
    :param imagined: detached (pi_G features, pi_E features, pi_G returns, pi_E returns, pi_G's decoded achieved
        goals).
    :param goals: symlog goals of pi_G.
    :param groups: replayed sequence of each start (negatives of the distance come from other sequences).
    :param replay_pairs: replayed pairs, or None.
    :param gamma: discount.
    :param unit: steps that make distance 1.
    :param n_pairs: pairs of imagined paths per distance update.
    :param neg_fraction: negatives per positive pair of the distance loss.
    :return: (summed loss, detached metrics).
    """
    feats_g, feats_e, returns_g, returns_e, imagined_goals = imagined
    critic_g_loss = critic_loss(policy.critic_g, feats_g, returns_g, goals, gamma)
    critic_e_loss = critic_loss(policy.critic_e, feats_e, returns_e, None, gamma)
    distance_loss = policy.distance.trajectory_loss(imagined_goals, n_pairs, unit, neg_fraction, groups=groups)
    if replay_pairs is not None:
        distance_loss = distance_loss + policy.distance.loss(*replay_pairs[:3], unit, replay_pairs[3])
    metrics = {"critic_g_loss": critic_g_loss, "critic_e_loss": critic_e_loss, "distance_loss": distance_loss}
    return critic_g_loss + critic_e_loss + distance_loss, {k: v.detach() for k, v in metrics.items()}
