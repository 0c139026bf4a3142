"""Probes of the world-model MoReFree agent's pieces against ground truth (why it learns, or does not).

Four figures, each computed on the agent's own replay data:

* :func:`distance_rank_correlation`: Spearman rank correlation between the learned dynamical distance
  ``D(achieved, goal)`` and the env's true distance between the same points (``path_distance`` when the env
  defines it, e.g. the shortest path through a maze; the Euclidean distance otherwise). Near 1: D orders states as
  the task's geometry does; near 0: pi_G's reward carries no information about where the goal is.
* :func:`goal_sensitivity`: mean absolute difference between pi_G's actions (the mode) in the same latent states
  under two different goals, as a fraction of the action range. An actor that ignores its goal scores 0; an
  untrained actor of the same architecture scores the reference level.
* :func:`critic_calibration`: standard deviation of V_G over imagination starts divided by the standard deviation
  of their lambda-returns. About 1: the critic follows the returns it regresses; near 0: a flat critic whose
  bootstrap gives pi_G no long-horizon gradient.
* :func:`distance_minimum_error`: how far from the goal the learned distance puts its minimum, beyond the replayed
  state nearest to it (0: pi_G's reward peaks at the goal).

and one probe on the task itself, :func:`evaluation_rollouts`: pi_G's evaluation episodes in the real env beside the
world model's prediction of the same episodes (is a failure the model's, which thinks pi_G gets there, or the
learners', whose pi_G fails in the model too?).

:class:`MoReFreeDiagnosticsCallback` logs them under ``diagnostics/`` during training (and prints them with
``verbose=1``, a line :func:`parse_diagnostics` reads back); ``scripts/diagnose_morefree.py`` prints them for a run or
a saved model.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

import gymnasium as gym
import numpy as np
import torch as th
from scipy.stats import spearmanr
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.envs.tasks import find_task
from sb3_gcrl.morefree.networks import Actor, LatentState, symexp, symlog

if TYPE_CHECKING:
    from sb3_gcrl.morefree.morefree import MoReFree


def true_distance(env: Any, achieved: np.ndarray, goal: np.ndarray) -> np.ndarray:
    """Ground-truth distance from each point of ``achieved (N, G)`` to ``goal (G,)``: the env's
    ``path_distance`` (e.g. shortest paths through a maze) when it has one, else the Euclidean distance.

    :param env: a gymnasium env (wrapped or not) or a :class:`VecEnvGeometry`.
    """
    if isinstance(env, VecEnvGeometry):
        if env.has_path_distance:
            return np.asarray(env.path_distance(achieved, goal), dtype=np.float64)
        base = None
    else:
        base = getattr(env, "unwrapped", env)
    if base is not None and hasattr(base, "path_distance"):
        return np.asarray(base.path_distance(achieved, goal), dtype=np.float64)
    return np.linalg.norm(np.asarray(achieved, np.float64) - np.asarray(goal, np.float64).reshape(1, -1), axis=-1)


class VecEnvGeometry:
    """The ground truth of the first env of a VecEnv, for :func:`true_distance`: its ``path_distance`` called through
    ``VecEnv.env_method`` (so that it works in any VecEnv, a ``SubprocVecEnv`` included), else Euclidean distances.

    :param env: the VecEnv.
    """

    def __init__(self, env: VecEnv) -> None:
        self.env = env
        self.has_path_distance = env.has_attr("path_distance")

    def path_distance(self, achieved: np.ndarray, goal: np.ndarray) -> np.ndarray:
        """The first env's ``path_distance(achieved, goal)``."""
        return self.env.env_method("path_distance", achieved, goal, indices=[0])[0]


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


def _learned_and_true_distances(
    model: MoReFree, env: Any, n_states: int, n_goals: int, seed: int, goals: str
) -> list[tuple[np.ndarray, np.ndarray]]:
    """``(D(s, g), true distance(s, g))`` over ``n_states`` replayed states ``s``, for each of ``n_goals`` goals
    (``"replay"``: replayed achieved goals; ``"evaluation"``: rho_g*)."""
    rng = np.random.default_rng(seed)
    goal_dim = model.policy.goal_dim
    achieved = model.replay_buffer.sample_states(n_states, rng)[:, -goal_dim:]
    if goals == "replay":
        targets = model.replay_buffer.sample_states(n_goals, rng)[:, -goal_dim:]
    elif goals == "evaluation":
        targets = model._task_goal_samples("evaluation", n_goals).reshape(-1, goal_dim)
    else:
        raise ValueError(f"goals must be 'replay' or 'evaluation', got {goals!r}")
    pairs = []
    with th.no_grad():
        points = symlog(th.as_tensor(achieved, dtype=th.float32, device=model.device))
        for goal in targets:
            target = symlog(th.as_tensor(goal, dtype=th.float32, device=model.device)).expand_as(points)
            pairs.append((model.policy.distance(points, target).cpu().numpy(), true_distance(env, achieved, goal)))
    return pairs


def distance_rank_correlation(
    model: MoReFree, env: Any, n_states: int = 512, n_goals: int = 8, seed: int = 0, goals: str = "replay"
) -> float:
    """Spearman correlation of ``D(s, g)`` with the true distance over replayed states ``s`` and ``n_goals`` goals.

    :param model: the agent (its replay buffer holds the states).
    :param env: the env whose geometry is the ground truth (see :func:`true_distance`).
    :param n_states: replayed states.
    :param n_goals: goals; the pairs of all of them are pooled.
    :param seed: seed of the draws.
    :param goals: ``"replay"`` (replayed achieved goals: does D know the geometry of the data?) or
        ``"evaluation"`` (rho_g*: does pi_G's reward point to the task's goals?).
    :return: the rank correlation (nan if the distances are constant).
    """
    pairs = _learned_and_true_distances(model, env, n_states, n_goals, seed, goals)
    learned, truth = zip(*pairs, strict=True)
    d, t = np.concatenate(learned), np.concatenate(truth)
    finite = np.isfinite(t)
    return float(spearmanr(d[finite], t[finite]).statistic)


def distance_minimum_error(
    model: MoReFree, env: Any, n_states: int = 4096, n_goals: int = 8, seed: int = 0, goals: str = "evaluation"
) -> float:
    """How far from its goal the learned distance puts its minimum: over ``n_states`` replayed states ``s``, the true
    distance to ``g`` of ``argmin_s D(s, g)`` minus that of the replayed state truly nearest to ``g``, mean over
    ``n_goals`` goals.

    0: of the replayed states, D's nearest to the goal is the nearest one (pi_G's reward peaks at the goal); a value
    near the success radius: pi_G is rewarded for stopping beside the goal, not in it.

    :param model: the agent (its replay buffer holds the states).
    :param env: the env whose geometry is the ground truth (see :func:`true_distance`).
    :param n_states: replayed states (the candidates; more of them reach closer to each goal).
    :param n_goals: goals.
    :param seed: seed of the draws.
    :param goals: ``"evaluation"`` (rho_g*) or ``"replay"`` (replayed achieved goals).
    :return: the mean error in the env's units (nan when no goal has a finite true distance to any state).
    """
    errors = []
    for learned, truth in _learned_and_true_distances(model, env, n_states, n_goals, seed, goals):
        finite = np.isfinite(truth)
        if finite.any():
            best = int(np.flatnonzero(finite)[np.argmin(learned[finite])])
            errors.append(truth[best] - truth[finite].min())
    return float(np.mean(errors)) if errors else float("nan")


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


def critic_calibration(model: MoReFree, n_starts: int = 512, seed: int = 0) -> float:
    """``std(V_G(s_0, g)) / std(R^lambda_0)`` over imagination starts ``s_0`` and their lambda-returns.

    The starts are posterior latents of replayed states, the goals drawn as in training (Sec. 3.4.2); the returns
    come from pi_G imagined as in training, bootstrapped from the slow critic.

    :param model: the agent.
    :param n_starts: imagination starts (rounded to whole replayed sequences).
    :param seed: seed of the draws.
    :return: the ratio (nan when the returns do not vary).
    """
    rng = np.random.default_rng(seed)
    policy = model.policy
    latent, achieved = _replay_latents(model, max(1, n_starts // model.batch_length), rng)
    achieved_np = achieved.cpu().numpy()
    goals_np = model.sample_imagination_goals(latent.deter.shape[0], achieved_np, achieved_np)[0]
    goals = symlog(th.as_tensor(goals_np, device=model.device))
    with th.no_grad():
        feats, _, _ = model._imagine(latent, goals)
        feats_g = feats[:, : goals.shape[0]]
        rewards = model._goal_rewards(policy.world_model.decode_goal(feats_g), goals)
        returns = model._returns(feats_g, rewards, policy.critic_g_target, goals)
        values = policy.critic_g(feats_g[0], goals)
    spread = returns[0].std().item()
    return float(values.std().item() / spread) if spread > 0 else float("nan")


def _finite_mean(x: np.ndarray) -> float:
    """Mean of the finite entries (a point inside a wall has no path distance), nan when there are none."""
    finite = x[np.isfinite(x)]
    return float(finite.mean()) if finite.size else float("nan")


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
        _finite_mean(final_distance),
        _finite_mean(imagined_distance),
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
    goals = model._task_goal_samples("evaluation", n_goals).reshape(-1, goal_dim)
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
        return _finite_mean(np.concatenate(parts)) if parts else float("nan")

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
    results = []
    for acting in ("pi_g", "zero"):
        latent, feats = start, [start.feat]
        for _ in range(horizon):
            if acting == "pi_g":
                action = policy.actor_g.act(latent.feat, goals, deterministic=True)[0]
            else:
                action = th.zeros(len(goals), policy.action_space.shape[0], device=model.device)
            latent = policy.world_model.rssm.img_step(latent, action, True)
            feats.append(latent.feat)
        feat = th.stack(feats)
        rewards = model._goal_rewards(policy.world_model.decode_goal(feat), goals)
        returns = model._returns(feat, rewards, policy.critic_g_target, goals)
        bootstrap = model.gamma**horizon * policy.critic_g_target(feat[-1], goals)
        results.append((returns[0], discounts @ rewards, bootstrap))
    return tuple((a - b).cpu().numpy() for a, b in zip(*results, strict=True))


def diagnose(
    model: MoReFree, env: Any, n: int = 512, seed: int = 0, rollout_envs: Sequence[gym.Env] = ()
) -> dict[str, float]:
    """All probes: ``distance_rank_correlation`` (replayed goals), ``distance_rank_correlation_task`` (evaluation
    goals), ``distance_minimum_error`` (evaluation goals, ``8 n`` candidate states), ``goal_sensitivity``,
    ``goal_sensitivity_untrained``, ``critic_calibration`` (see the module docstring), and with ``rollout_envs`` the
    figures of :func:`evaluation_rollouts` (one episode per env) and, for a task of this package that states its
    success radius, those of :func:`goal_holding`.

    The probes leave the agent's random numbers as they found them (PyTorch's and the agent's generator): training
    goes on as it would have without them."""
    with _own_random_numbers(model, seed):
        return _diagnose(model, env, n, seed, rollout_envs)


@contextmanager
def _own_random_numbers(model: MoReFree, seed: int) -> Iterator[None]:
    """Probes draw from their own generators: PyTorch's state and the agent's generator are put back afterwards, so
    that a run trains the same with and without probes."""
    devices = [model.device] if model.device.type == "cuda" else []
    agent_rng = model._rng
    model._rng = np.random.default_rng(seed)
    try:
        with th.random.fork_rng(devices=devices):
            yield
    finally:
        model._rng = agent_rng


def _diagnose(model: MoReFree, env: Any, n: int, seed: int, rollout_envs: Sequence[gym.Env]) -> dict[str, float]:
    figures = {
        "distance_rank_correlation": distance_rank_correlation(model, env, n, seed=seed),
        "distance_rank_correlation_task": distance_rank_correlation(model, env, n, seed=seed, goals="evaluation"),
        "distance_minimum_error": distance_minimum_error(model, env, 8 * n, seed=seed),
        "goal_sensitivity": goal_sensitivity(model, n, seed),
        "goal_sensitivity_untrained": untrained_goal_sensitivity(model, n, seed),
        "critic_calibration": critic_calibration(model, n, seed),
    }
    if rollout_envs:
        figures.update(evaluation_rollouts(model, rollout_envs, seed=seed * len(rollout_envs)))
        task = find_task(rollout_envs[0])
        if task is not None and task.success_threshold is not None:
            figures.update(goal_holding(model, env, task.success_threshold, seed=seed))
    return figures


#: what starts the line :class:`MoReFreeDiagnosticsCallback` prints with ``verbose=1`` (read back by
#: :func:`parse_diagnostics`, e.g. from a comparison run's ``train.log``)
LINE_PREFIX = "diagnostics at "


def format_diagnostics(step: int, figures: dict[str, float]) -> str:
    """The printed line of one probe: ``diagnostics at <step>: <name> <value>, ...``."""
    return f"{LINE_PREFIX}{step}: " + ", ".join(f"{name} {value:.4f}" for name, value in figures.items())


def parse_diagnostics(text: str) -> list[tuple[int, dict[str, float]]]:
    """The probes printed in ``text`` (lines of :func:`format_diagnostics`), in order."""
    probes = []
    for line in text.splitlines():
        if not line.startswith(LINE_PREFIX):
            continue
        step, _, rest = line[len(LINE_PREFIX) :].partition(": ")
        pairs = (item.rsplit(" ", 1) for item in rest.split(", ") if item)
        probes.append((int(step), {name: float(value) for name, value in pairs}))
    return probes


class MoReFreeDiagnosticsCallback(BaseCallback):
    """Log :func:`diagnose` under ``diagnostics/`` every ``diagnose_freq`` env steps once training has started.

    :param diagnose_freq: env steps between probes.
    :param n: states (and imagination starts) per probe.
    :param rollout_episodes: evaluation episodes of :func:`evaluation_rollouts` per probe (0: none).
    :param rollout_env: the env of those episodes: an env id or a function that makes the env; ``None``: the
        training env's registered env (``gym.make`` of its spec without the wrappers added around it, so with its
        registered time limit: the evaluation episode of the task).
    :param verbose: print the figures when >= 1.
    """

    def __init__(
        self,
        diagnose_freq: int = 5000,
        n: int = 512,
        rollout_episodes: int = 10,
        rollout_env: str | Callable[[], gym.Env] | None = None,
        verbose: int = 0,
    ) -> None:
        super().__init__(verbose)
        if diagnose_freq < 1 or n < 2 or rollout_episodes < 0:
            raise ValueError(
                f"diagnose_freq must be >= 1, n >= 2 and rollout_episodes >= 0, got {diagnose_freq}, {n}, "
                f"{rollout_episodes}"
            )
        if rollout_env is not None and not (isinstance(rollout_env, str) or callable(rollout_env)):
            raise TypeError(f"rollout_env must be an env id, a function that makes an env or None, got {rollout_env!r}")
        self.diagnose_freq, self.n, self.rollout_episodes = diagnose_freq, n, rollout_episodes
        self.rollout_env = rollout_env
        self._next = diagnose_freq
        #: (timestep, figures) of every probe so far
        self.history: list[tuple[int, dict[str, float]]] = []
        self._geometry: VecEnvGeometry | None = None
        self._rollout_envs: list[gym.Env] = []

    def _make_rollout_env(self) -> gym.Env:
        if isinstance(self.rollout_env, str):
            return gym.make(self.rollout_env)
        if self.rollout_env is not None:
            return self.rollout_env()
        spec = self.training_env.get_attr("spec", indices=[0])[0]
        if spec is None:
            raise ValueError(
                "MoReFreeDiagnosticsCallback: the training env was not made by gym.make, so its evaluation env is "
                "unknown; pass rollout_env (an env id or a function that makes the env) or rollout_episodes=0"
            )
        return gym.make(dataclasses.replace(spec, additional_wrappers=()))

    def _init_callback(self) -> None:
        if not self.rollout_episodes:
            return
        self._rollout_envs = [self._make_rollout_env() for _ in range(self.rollout_episodes)]
        space = self._rollout_envs[0].observation_space
        if space != self.model.observation_space:
            raise ValueError(
                f"MoReFreeDiagnosticsCallback: the rollout env's observation space {space} is not the agent's "
                f"{self.model.observation_space}; pass rollout_env (an env id or a function that makes the env)"
            )

    def _on_step(self) -> bool:
        model = self.model
        if self.num_timesteps < self._next:
            return True
        self._next = self.num_timesteps + self.diagnose_freq
        if getattr(model, "_n_updates", 0) == 0:
            return True
        if self._geometry is None:
            self._geometry = VecEnvGeometry(self.training_env)
        figures = diagnose(
            model,  # type: ignore[arg-type]
            self._geometry,
            self.n,
            seed=len(self.history),
            rollout_envs=self._rollout_envs,
        )
        self.history.append((self.num_timesteps, figures))
        for name, value in figures.items():
            self.logger.record(f"diagnostics/{name}", value)
        if self.verbose >= 1:
            print(format_diagnostics(self.num_timesteps, figures), flush=True)
        return True

    def _on_training_end(self) -> None:
        for env in self._rollout_envs:
            env.close()
        self._rollout_envs = []
