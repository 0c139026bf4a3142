"""A probe of the model-based MoReFree agent on the task itself: pi_G's evaluation episodes in the real env beside
the world model's prediction of the same episodes (:func:`evaluation_rollouts`). Is a failure the model's, which
thinks pi_G gets there, or the learners', whose pi_G fails in the model too?
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch as th
from scipy.stats import spearmanr

from sb3_gcrl.envs.tasks import find_task
from sb3_gcrl.morefree.functional import symexp, symlog
from sb3_gcrl.morefree.networks import LatentState
from sb3_gcrl.morefree.probes.distance import finite_mean, true_distance

if TYPE_CHECKING:
    from sb3_gcrl.morefree.morefree import MoReFree


def _rank_correlation(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman correlation, nan for fewer than 3 points or a constant side."""
    if a.size < 3 or np.ptp(a) == 0 or np.ptp(b) == 0:
        return float("nan")
    return float(spearmanr(a, b).statistic)


#: the figures of :func:`evaluation_rollouts`, in order
ROLLOUT_FIGURES = (
    "rollout_success",
    "rollout_reached",
    "rollout_held",
    "rollout_imagined_success",
    "rollout_optimism",
    "rollout_final_distance",
    "rollout_imagined_final_distance",
    "rollout_imagined_outside",
    "rollout_model_error",
    "rollout_reconstruction_error",
    "rollout_distance_correlation",
    "rollout_distance_correlation_near",
)


def _achieved(observations: list[dict[str, Any]]) -> np.ndarray:
    return np.stack([np.asarray(o["achieved_goal"], dtype=np.float64).reshape(-1) for o in observations])


def evaluation_rollouts(
    model: MoReFree, envs: Sequence[gym.Env], seed: int = 0, success_threshold: float | None = None
) -> dict[str, float]:
    """pi_G's evaluation episodes in the real env beside the world model's prediction of the same episodes.

    Each env runs one episode (``reset(seed=seed + i)``), acted as ``evaluate_policy`` acts: the latent filtered
    across the episode, the posterior's mode, pi_G's deterministic action toward the episode's goal. Beside it:

    * the *imagined* episode: from the first posterior, pi_G's deterministic actions rolled through the world model's
      prior (its mode) for as many steps as the real episode, i.e. what pi_G expects from that start;
    * the *model error*: from every posterior of the real episode, the real actions of the next
      ``imagination_horizon`` steps rolled through the prior, the decoded achieved goal compared with the real one
      (the model's accuracy where pi_G goes, over the horizon pi_G is trained on);
    * the learned distance ``D(achieved_t, g)`` along the real path against the true one (:func:`true_distance`).

    A failure the model also predicts (pi_G fails in imagination too) is the learners'; a success only the model
    sees (``rollout_optimism``) is the model's.

    :param model: the agent.
    :param envs: evaluation envs (episodic: a time limit or terminations end their episodes), one episode each, with
        the observation space the agent was trained on.
    :param seed: seed of the first env's reset.
    :param success_threshold: distance to the goal within which the imagined episode counts as a success (the
        env's own test); ``None``: the task's (:func:`~sb3_gcrl.envs.tasks.find_task`), nan for an env of your own.
    :return: ``rollout_success`` (share of real episodes with ``info["is_success"]`` at their end),
        ``rollout_reached`` (share of real episodes that come within ``success_threshold`` of the goal at some
        step), ``rollout_held`` (of the steps from the first such step to the episode's end, the share spent there;
        mean over the episodes that reached it: 1 for a policy that stops at the goal, low for one that passes it),
        ``rollout_imagined_success`` (share whose imagined episode ends within ``success_threshold`` of the goal),
        ``rollout_optimism`` (share imagined a success and not one in the env), ``rollout_final_distance`` and
        ``rollout_imagined_final_distance`` (mean true distance of the real / imagined final achieved goal to the
        goal, over the ends that have one), ``rollout_imagined_outside`` (share of imagined episodes that end where
        the true distance is undefined, e.g. inside a maze's wall), ``rollout_model_error`` (mean distance between
        the predicted and the real achieved goal ``imagination_horizon`` steps ahead),
        ``rollout_reconstruction_error`` (the same at 0 steps: the decoder's error on the posterior),
        ``rollout_distance_correlation`` (Spearman of D with the true distance along the real paths) and
        ``rollout_distance_correlation_near`` (the same over the states within twice ``success_threshold`` of the
        goal: can D still tell the goal from its surroundings, at the scale of the success test?); distances in the
        env's units.
    """
    if not envs:
        raise ValueError("evaluation_rollouts needs at least one env")
    if success_threshold is None:
        task = find_task(envs[0])
        success_threshold = None if task is None else task.success_threshold
    policy, device, n = model.policy, model.device, len(envs)
    with th.no_grad():
        episodes = _play_episodes(model, envs, seed)
        imagined_final = _imagined_ends(model, episodes)
        reconstruction_error, model_error = _model_errors(model, episodes)
        # the learned and the true distance along the real paths (whose last point is the real end), and the true
        # distance of the imagined end, in one ground-truth call per episode
        learned, truth = [], []
        final_distance, imagined_distance = np.zeros(n), np.zeros(n)
        for i in range(n):
            path = episodes.paths[: episodes.lengths[i] + 1, i]
            points = symlog(th.as_tensor(path, dtype=th.float32, device=device))
            learned.append(policy.distance(points, episodes.goals[i].expand_as(points)).cpu().numpy())
            distances = true_distance(envs[i], np.vstack([path, imagined_final[i]]), episodes.goals_raw[i])
            truth.append(distances[:-1])
            final_distance[i], imagined_distance[i] = distances[-2], distances[-1]
    learned_all, truth_all = np.concatenate(learned), np.concatenate(truth)
    finite = np.isfinite(truth_all)
    near = finite & (truth_all <= 2 * success_threshold) if success_threshold is not None else np.zeros_like(finite)
    goals_raw, lengths, success = episodes.goals_raw, episodes.lengths, episodes.success
    reached, held = np.full(n, np.nan), np.full(n, np.nan)
    if success_threshold is None:
        imagined_success = np.full(n, np.nan)
    else:
        imagined_success = (np.linalg.norm(imagined_final - goals_raw, axis=-1) <= success_threshold).astype(float)
        in_goal = np.linalg.norm(episodes.paths[1:] - goals_raw[None], axis=-1) <= success_threshold  # (steps, n)
        for i in range(n):
            visits = in_goal[: lengths[i], i]
            reached[i] = float(visits.any())
            if visits.any():
                held[i] = float(visits[int(np.argmax(visits)) :].mean())
    figures = (
        float(np.mean(success)),
        float(np.mean(reached)),
        float(np.nanmean(held)) if np.isfinite(held).any() else float("nan"),
        float(np.mean(imagined_success)),
        float(np.mean(imagined_success * (1.0 - success))),
        finite_mean(final_distance),
        finite_mean(imagined_distance),
        float(np.mean(~np.isfinite(imagined_distance))),
        float(model_error.mean()) if model_error.size else float("nan"),
        float(reconstruction_error.mean()),
        _rank_correlation(learned_all[finite], truth_all[finite]),
        _rank_correlation(learned_all[near], truth_all[near]),
    )
    return dict(zip(ROLLOUT_FIGURES, figures, strict=True))


@dataclasses.dataclass
class _Episodes:
    """pi_G's evaluation episodes, played in lock-step (rows past an episode's end repeat its last state)."""

    #: posterior latents ``steps x (n, ...)`` and pi_G's actions ``steps x (n, A)`` taken in them
    posts: list[LatentState]
    actions: list[th.Tensor]
    #: achieved goals ``(steps + 1, n, G)``, episode lengths ``(n,)``, ``is_success`` at each episode's end ``(n,)``
    paths: np.ndarray
    lengths: np.ndarray
    success: np.ndarray
    #: the episodes' goals, raw ``(n, G)`` and symlog ``(n, G)`` (a tensor)
    goals_raw: np.ndarray
    goals: th.Tensor


def _play_episodes(model: MoReFree, envs: Sequence[gym.Env], seed: int) -> _Episodes:
    """One episode per env (``reset(seed=seed + i)``), acted as ``predict`` with ``episode_start`` acts."""
    policy, n = model.policy, len(envs)
    observations = [env.reset(seed=seed + i)[0] for i, env in enumerate(envs)]
    goals_raw = np.stack([np.asarray(o["desired_goal"], dtype=np.float64).reshape(-1) for o in observations])
    goals = symlog(th.as_tensor(goals_raw, dtype=th.float32, device=model.device))
    latent = policy.world_model.rssm.initial(n, model.device)
    action = th.zeros(n, policy.action_space.shape[0], device=model.device)
    alive, lengths, success = np.ones(n, dtype=bool), np.zeros(n, dtype=np.int64), np.zeros(n)
    posts: list[LatentState] = []
    actions: list[th.Tensor] = []
    achieved = [_achieved(observations)]
    while alive.any():
        states, _ = policy.states_to_tensor({k: np.stack([o[k] for o in observations]) for k in observations[0]})
        latent = policy.filter(latent, action, states, deterministic=True)
        action = policy.actor_g.act(latent.feat, goals, deterministic=True)[0]
        posts.append(latent)
        actions.append(action)
        env_actions = policy.unscale_action(action.cpu().numpy())
        for i in np.flatnonzero(alive):
            observations[i], _, terminated, truncated, info = envs[i].step(env_actions[i])
            lengths[i] += 1
            if terminated or truncated:
                alive[i] = False
                success[i] = float(info.get("is_success", np.nan))
        achieved.append(_achieved(observations))
    return _Episodes(posts, actions, np.stack(achieved), lengths, success, goals_raw, goals)


def _imagined_ends(model: MoReFree, episodes: _Episodes) -> np.ndarray:
    """The achieved goal ``(n, G)`` at which pi_G, rolled through the prior's mode from each episode's first
    posterior for as many steps as the real episode, ends."""
    policy = model.policy
    imagined, ends_at = episodes.posts[0], np.zeros((len(episodes.lengths), policy.goal_dim))
    for t in range(len(episodes.actions)):
        action = policy.actor_g.act(imagined.feat, episodes.goals, deterministic=True)[0]
        imagined = policy.world_model.rssm.img_step(imagined, action, True)
        ends = np.flatnonzero(episodes.lengths == t + 1)
        if ends.size:
            ends_at[ends] = symexp(policy.world_model.decode_goal(imagined.feat)).cpu().numpy()[ends]
    return ends_at


def _model_errors(model: MoReFree, episodes: _Episodes) -> tuple[np.ndarray, np.ndarray]:
    """The decoder's errors on the real episodes' posteriors, and the model's errors ``imagination_horizon`` steps
    ahead (from each posterior, the real actions through the prior's mode), over the steps inside the episodes."""
    policy, lengths = model.policy, episodes.lengths
    steps = len(episodes.actions)
    horizon = min(model.imagination_horizon, steps)
    starts = steps - horizon + 1
    every = LatentState(*(th.stack(field) for field in zip(*episodes.posts, strict=True)))
    decoded = symexp(policy.world_model.decode_goal(every.feat)).cpu().numpy()  # (steps, n, G)
    inside = np.arange(steps)[:, None] < lengths[None, :]
    reconstruction = np.linalg.norm(decoded - episodes.paths[:-1], axis=-1)[inside]
    latent = LatentState(*(x[:starts].flatten(0, 1) for x in every))
    for k in range(horizon):
        latent = policy.world_model.rssm.img_step(latent, th.cat(episodes.actions[k : k + starts]), True)
    predicted = symexp(policy.world_model.decode_goal(latent.feat)).cpu().numpy()
    ahead = (np.arange(starts)[:, None] + horizon <= lengths[None, :]).reshape(-1)
    error = np.linalg.norm(predicted - episodes.paths[horizon:].reshape(-1, predicted.shape[-1]), axis=-1)
    return reconstruction, error[ahead]
