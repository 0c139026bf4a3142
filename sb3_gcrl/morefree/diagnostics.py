"""Probes of the world-model MoReFree agent's pieces against ground truth (why it learns, or does not).

Three figures, each computed on the agent's own replay data:

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

:class:`MoReFreeDiagnosticsCallback` logs them under ``diagnostics/`` during training (and prints them with
``verbose=1``, a line :func:`parse_diagnostics` reads back); ``scripts/diagnose_morefree.py`` prints them for a run or
a saved model.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
import torch as th
from scipy.stats import spearmanr
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import VecEnv

from sb3_gcrl.morefree.networks import Actor, LatentState, symlog

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
    rng = np.random.default_rng(seed)
    goal_dim = model.policy.goal_dim
    achieved = model.replay_buffer.sample_states(n_states, rng)[:, -goal_dim:]
    if goals == "replay":
        targets = model.replay_buffer.sample_states(n_goals, rng)[:, -goal_dim:]
    elif goals == "evaluation":
        targets = model._task_goal_samples("evaluation", n_goals).reshape(-1, goal_dim)
    else:
        raise ValueError(f"goals must be 'replay' or 'evaluation', got {goals!r}")
    learned, truth = [], []
    with th.no_grad():
        points = symlog(th.as_tensor(achieved, dtype=th.float32, device=model.device))
        for goal in targets:
            target = symlog(th.as_tensor(goal, dtype=th.float32, device=model.device)).expand_as(points)
            learned.append(model.policy.distance(points, target).cpu().numpy())
            truth.append(true_distance(env, achieved, goal))
    d, t = np.concatenate(learned), np.concatenate(truth)
    finite = np.isfinite(t)
    return float(spearmanr(d[finite], t[finite]).statistic)


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
    latent, _ = _replay_latents(model, max(1, n_starts // model.batch_length), rng)
    goals = symlog(th.as_tensor(model.sample_imagination_goals(latent.deter.shape[0])[0], device=model.device))
    with th.no_grad():
        feats, _, _ = model._imagine(latent, goals)
        feats_g = feats[:, : goals.shape[0]]
        rewards = model._goal_rewards(policy.world_model.decode_goal(feats_g), goals)
        returns = model._returns(feats_g, rewards, policy.critic_g_target, goals)
        values = policy.critic_g(feats_g[0], goals)
    spread = returns[0].std().item()
    return float(values.std().item() / spread) if spread > 0 else float("nan")


def diagnose(model: MoReFree, env: Any, n: int = 512, seed: int = 0) -> dict[str, float]:
    """All probes: ``distance_rank_correlation`` (replayed goals), ``distance_rank_correlation_task`` (evaluation
    goals), ``goal_sensitivity``, ``goal_sensitivity_untrained``,
    ``critic_calibration`` (see the module docstring)."""
    return {
        "distance_rank_correlation": distance_rank_correlation(model, env, n, seed=seed),
        "distance_rank_correlation_task": distance_rank_correlation(model, env, n, seed=seed, goals="evaluation"),
        "goal_sensitivity": goal_sensitivity(model, n, seed),
        "goal_sensitivity_untrained": untrained_goal_sensitivity(model, n, seed),
        "critic_calibration": critic_calibration(model, n, seed),
    }


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
    :param verbose: print the figures when >= 1.
    """

    def __init__(self, diagnose_freq: int = 5000, n: int = 512, verbose: int = 0) -> None:
        super().__init__(verbose)
        if diagnose_freq < 1 or n < 2:
            raise ValueError(f"diagnose_freq must be >= 1 and n >= 2, got {diagnose_freq}, {n}")
        self.diagnose_freq, self.n = diagnose_freq, n
        self._next = diagnose_freq
        #: (timestep, figures) of every probe so far
        self.history: list[tuple[int, dict[str, float]]] = []
        self._geometry: VecEnvGeometry | None = None

    def _on_step(self) -> bool:
        model = self.model
        if self.num_timesteps < self._next:
            return True
        self._next = self.num_timesteps + self.diagnose_freq
        if getattr(model, "_n_updates", 0) == 0:
            return True
        if self._geometry is None:
            self._geometry = VecEnvGeometry(self.training_env)
        figures = diagnose(model, self._geometry, self.n, seed=len(self.history))  # type: ignore[arg-type]
        self.history.append((self.num_timesteps, figures))
        for name, value in figures.items():
            self.logger.record(f"diagnostics/{name}", value)
        if self.verbose >= 1:
            print(format_diagnostics(self.num_timesteps, figures), flush=True)
        return True
