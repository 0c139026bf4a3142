"""A probe of goal holding for the model-based MoReFree agent: does pi_G, started at its goal, stay there, and does
its own objective ask it to (:func:`goal_holding`, :func:`objective_gaps`)?
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th

from sb3_gcrl.morefree.functional import symexp, symlog
from sb3_gcrl.morefree.losses import imagine_path
from sb3_gcrl.morefree.networks import LatentState
from sb3_gcrl.morefree.probes.distance import finite_mean, true_distance

if TYPE_CHECKING:
    from sb3_gcrl.morefree.morefree import MoReFree


#: the figures of :func:`goal_holding`, in order
HOLD_FIGURES = (
    "hold_objective_gap",
    "hold_reward_gap",
    "hold_bootstrap_gap",
    "hold_return_gap",
    "hold_stay_share",
    "hold_leave_distance",
    "distance_at_goal",
    "distance_beside_goal",
    "value_at_goal",
    "value_beside_goal",
)


def goal_holding(
    model: MoReFree,
    env: Any,
    success_threshold: float,
    n_goals: int = 8,
    n_states: int = 4096,
    starts_per_goal: int = 8,
    horizon: int | None = None,
    seed: int = 0,
    goal_rng: np.random.Generator | None = None,
) -> dict[str, float]:
    """Does pi_G, started at its goal, stay there, and does its own objective ask it to?

    For each of ``n_goals`` evaluation goals ``g`` (rho_g*), the ``starts_per_goal`` replayed states truly nearest to
    ``g`` (of ``n_states``) are the starts, each as the memoryless latent of its observation
    (:meth:`~sb3_gcrl.morefree.policies.MoReFreePolicy.hold_latent`). From each, pi_G's deterministic actions are
    rolled through the prior's mode for ``horizon`` steps and scored with pi_G's own reward ``-D(achieved, g)``, beside
    the return of staying where it started (``-D`` of the start's decoded achieved goal at every step). pi_G's
    training objective from the same starts (the lambda-return over ``imagination_horizon`` imagined steps,
    bootstrapped from the slow critic) is compared with that of the zero action (the middle of the action box: do
    nothing, e.g. come to rest), split into the discounted rewards and the discounted bootstrap values. The replayed
    states split by their true distance to ``g`` into *at the goal* (within half the success radius) and *beside it*
    (one to two radii away), where D and V_G (of the states' memoryless latents) are compared.

    :param model: the agent (its replay buffer holds the states).
    :param env: the env whose geometry is the ground truth (see :func:`true_distance`).
    :param success_threshold: the task's success radius, in the env's units.
    :param n_goals: evaluation goals.
    :param n_states: replayed candidate states per goal.
    :param starts_per_goal: starts per goal (the replayed states nearest to it).
    :param horizon: imagined steps (``None``: four times ``imagination_horizon``).
    :param seed: seed of the draws.
    :param goal_rng: generator of the evaluation goals drawn as the agent draws them (``None``: the agent's own).
    :return: ``hold_objective_gap`` (pi_G's lambda-return minus the zero action's, mean over the starts: above 0,
        pi_G's objective prefers what pi_G does to doing nothing at its goal), ``hold_reward_gap`` (the same for
        the discounted sum of the imagined rewards alone) and ``hold_bootstrap_gap`` (for the discounted slow-critic
        value at the imagination's end; a positive objective gap with a negative reward gap is a critic that values
        leaving the goal above the reward of holding it), ``hold_return_gap`` (pi_G's discounted return minus that of
        staying at the start, per discounted step,
        in D's units, mean over the starts: below 0, pi_G leaves a place its own reward prefers; at or above 0, its
        objective does not ask it to stay), ``hold_stay_share`` (share of pi_G's imagined steps within
        ``success_threshold`` of ``g``), ``hold_leave_distance`` (mean true distance of the imagined end to ``g``),
        ``distance_at_goal`` / ``distance_beside_goal`` (mean ``D(s, g)`` over the replayed states at / beside the
        goal: the reward's step from the goal's surroundings into it) and ``value_at_goal`` / ``value_beside_goal``
        (the same for ``V_G(s, g)``); nan where a split holds no state.
    """
    policy, device, gamma = model.policy, model.device, model.gamma
    horizon = 4 * model.imagination_horizon if horizon is None else int(horizon)
    rng = np.random.default_rng(seed)
    goal_dim = policy.goal_dim
    goals = model.task_goal_samples("evaluation", n_goals, goal_rng).reshape(-1, goal_dim)
    discounts = gamma ** np.arange(horizon)
    gaps, stays, leaves = [], [], []
    objective: dict[str, list[np.ndarray]] = {"objective": [], "reward": [], "bootstrap": []}
    split: dict[str, tuple[list[np.ndarray], list[np.ndarray]]] = {"at": ([], []), "beside": ([], [])}
    with th.no_grad():
        for goal in goals:
            states = model.replay_buffer.sample_states(n_states, rng)
            truth = true_distance(env, states[:, -goal_dim:], goal)
            finite = np.flatnonzero(np.isfinite(truth))
            if finite.size == 0:
                continue
            target = symlog(th.as_tensor(goal, dtype=th.float32, device=device)).reshape(1, -1)
            nearest = finite[np.argsort(truth[finite], kind="stable")[:starts_per_goal]]
            latent = policy.hold_latent(th.as_tensor(states[nearest], device=device), deterministic=True)
            goal_rows = target.expand(len(nearest), -1)
            for name, gap in zip(objective, objective_gaps(model, latent, goal_rows), strict=True):
                objective[name].append(gap)
            start_reward = -policy.distance(policy.world_model.decode_goal(latent.feat), goal_rows)
            rewards = []
            for _ in range(horizon):
                action = policy.actor_g.act(latent.feat, goal_rows, deterministic=True)[0]
                latent = policy.world_model.rssm.img_step(latent, action, True)
                achieved = policy.world_model.decode_goal(latent.feat)
                rewards.append(-policy.distance(achieved, goal_rows))
                stays.append(
                    (np.linalg.norm(symexp(achieved).cpu().numpy() - goal, axis=-1) <= success_threshold).astype(float)
                )
            returns = discounts @ th.stack(rewards).cpu().numpy()
            gaps.append((returns - discounts.sum() * start_reward.cpu().numpy()) / discounts.sum())
            leaves.append(true_distance(env, symexp(achieved).cpu().numpy().astype(np.float64), goal))
            for name, rows in (
                ("at", finite[truth[finite] <= success_threshold / 2]),
                ("beside", finite[(truth[finite] >= success_threshold) & (truth[finite] <= 2 * success_threshold)]),
            ):
                if rows.size == 0:
                    continue
                points = th.as_tensor(states[rows], device=device)
                feat = policy.hold_latent(points, deterministic=True).feat
                rows_goal = target.expand(len(rows), -1)
                split[name][0].append(policy.distance(symlog(points[:, -goal_dim:]), rows_goal).cpu().numpy())
                split[name][1].append(policy.critic_g(feat, rows_goal).cpu().numpy())

    def mean(parts: list[np.ndarray]) -> float:
        return finite_mean(np.concatenate(parts)) if parts else float("nan")

    return dict(
        zip(
            HOLD_FIGURES,
            (
                mean(objective["objective"]),
                mean(objective["reward"]),
                mean(objective["bootstrap"]),
                mean(gaps),
                mean(stays),
                mean(leaves),
                mean(split["at"][0]),
                mean(split["beside"][0]),
                mean(split["at"][1]),
                mean(split["beside"][1]),
            ),
            strict=True,
        )
    )


def objective_gaps(model: MoReFree, start: LatentState, goals: th.Tensor) -> tuple[np.ndarray, ...]:
    """pi_G's deterministic actions against the zero action (do nothing) from the same starts, over
    ``imagination_horizon`` imagined steps (the prior's mode), as pi_G's training objective scores them.

    :param model: the agent.
    :param start: latent starts ``(N, ...)``.
    :param goals: symlog goals ``(N, G)``.
    :return: per start, pi_G's minus the zero action's lambda-return (bootstrapped from the slow critic), discounted
        reward sum and discounted bootstrap value at the end.
    """
    policy, horizon = model.policy, model.imagination_horizon
    discounts = model.gamma ** th.arange(horizon, dtype=th.float32, device=model.device)
    no_action = th.zeros(len(goals), policy.action_space.shape[0], device=model.device)
    acting: list[Callable[[th.Tensor], th.Tensor]] = [
        lambda feat: policy.actor_g.act(feat, goals, deterministic=True)[0],
        lambda feat: no_action,
    ]
    results = []
    for act in acting:
        feat, _ = imagine_path(policy.world_model.rssm, start, act, horizon, mode=True)
        rewards = model.goal_rewards(policy.world_model.decode_goal(feat), goals)
        returns = model.lambda_returns(feat, rewards, policy.critic_g_target, goals)
        bootstrap = model.gamma**horizon * policy.critic_g_target(feat[-1], goals)
        results.append((returns[0], discounts @ rewards, bootstrap))
    return tuple((a - b).cpu().numpy() for a, b in zip(*results, strict=True))
