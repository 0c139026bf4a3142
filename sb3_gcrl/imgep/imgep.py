"""Tabular IMGEP with post-exploration and hindsight relabeling (thesis Ch. 6, Algorithm 3).

Each episode: sample a goal from the goal space of visited states by count-based novelty (Eq. 6.5), reset, act
epsilon-greedily with a goal-conditioned Q-table towards it; if the goal is reached and post-exploration is on,
take random actions for as many steps as the :mod:`~sb3_gcrl.post_exploration.rules` rule says (thesis Table 6.2:
``p_pe = 0.5`` of the path length), then end the episode; without post-exploration the episode ends at the goal.
The goal space and its counts are updated with every visited state, and the Q-table is updated with Eq. 6.2 on
the episode for the commanded goal and for hindsight goals (Sec. 6.4.2): half of the trajectory's states,
always including the whole post-exploration part, are relabeled as goals.

The policy is goal-conditioned: its observation space is the Dict of :class:`TabularGoalEnv` (``observation``,
``achieved_goal``, ``desired_goal``). :meth:`TabularIMGEP.predict` also takes a bare state of the plain tabular
env and then commands the goal of the env's own task (:attr:`TabularGoalEnv.task_goal`, the goal tile's cell
for MiniGrid), so ``evaluate_policy`` and SB3's ``EvalCallback`` work on the plain env too.
"""

from __future__ import annotations

import sys
import time
from typing import Any, TypeVar

import gymnasium as gym
import numpy as np
from stable_baselines3.common.base_class import BaseAlgorithm
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.type_aliases import GymEnv, MaybeCallback
from stable_baselines3.common.utils import safe_mean
from stable_baselines3.common.vec_env import DummyVecEnv

from sb3_gcrl.common.metrics import coverage, visitation_entropy
from sb3_gcrl.common.saving import ModelFileMixin
from sb3_gcrl.common.seeding import SeededGeneratorMixin
from sb3_gcrl.common.validation import check_bool, check_float, check_int, check_step_size, check_unit_interval
from sb3_gcrl.goals.goal_space import BinnedGoalSpace
from sb3_gcrl.imgep.policies import TabularGoalPolicy
from sb3_gcrl.imgep.tabular_goal_env import TabularGoalEnv
from sb3_gcrl.post_exploration.evaluation import recreate_env
from sb3_gcrl.post_exploration.interface import GoalExplorationAgent
from sb3_gcrl.post_exploration.rules import PostExplorationRule, ProportionalSteps, make_post_exploration_rule

SelfTabularIMGEP = TypeVar("SelfTabularIMGEP", bound="TabularIMGEP")


class TabularIMGEP(SeededGeneratorMixin, ModelFileMixin, BaseAlgorithm, GoalExplorationAgent):
    """Goal-conditioned tabular Q-learning in an IMGEP loop, with optional post-exploration (Algorithm 3).

    The agent keeps its goal space and visit counts itself, so it implements
    :class:`~sb3_gcrl.post_exploration.interface.GoalExplorationAgent` (:meth:`visitation_entropy`,
    :meth:`coverage`, :meth:`make_all_goals_env`) for :class:`~sb3_gcrl.post_exploration.AllGoalsEvalCallback`.

    :param policy: ``"TabularGoalPolicy"`` or ``"MultiInputPolicy"`` (the same; or the class).
    :param env: a tabular env (Discrete observation and actions, e.g. ``"GCRL/FourRoomsTabular-v0"``) or a
        :class:`~sb3_gcrl.imgep.TabularGoalEnv`; plain tabular envs are wrapped in one (MiniGrid: goals are cells).
        The model's ``observation_space`` is that goal env's Dict; :meth:`predict` also takes the plain env's
        bare states (goal: the env's own task goal, see :attr:`task_goal`).
    :param learning_rate: alpha of Eq. 6.2 (Table 6.2: 0.1), or a schedule of the remaining progress.
    :param gamma: discount of Eq. 6.2 (Table 6.2: 0.99).
    :param epsilon: probability of a random action while going to the goal (Table 6.2: 0, 0.1 or 0.3).
    :param tau: temperature of the count-based novelty goal sampling, Eq. 6.5 (Table 6.2: 0 = uniform).
    :param post_exploration: switch post-exploration on/off (the chapter's ablation).
    :param post_exploration_rule: length rule once the goal is reached (default ``ProportionalSteps(0.5)``,
        Table 6.2); :class:`~sb3_gcrl.post_exploration.NoveltyAdaptive` is our adaptive variant. A dict is passed
        to :func:`~sb3_gcrl.post_exploration.make_post_exploration_rule` (YAML: ``{p_pe: 0.5}``,
        ``{n_pe: 10}``, ``{adaptive: {beta: 1.0}}``).
    :param relabel_fraction: fraction of each trajectory's states relabeled as hindsight goals (Sec. 6.4.2:
        0.5); the post-exploration part is always relabeled in full.
    :param policy_kwargs: forwarded to the policy (``initial_value``).
    :param stats_window_size: episodes averaged in the ``rollout/`` logs.
    :param tensorboard_log: tensorboard directory.
    :param verbose: 0 silent, 1 training logs.
    :param seed: seed of the agent's random generator and the env (:meth:`set_random_seed` reseeds both; the
        generator's state is saved with the model, so a loaded model continues exactly).
    :param device: kept for SB3's signature; tables live on the CPU.
    :param _init_setup_model: build the table now (False when loading).
    """

    #: ``"MultiInputPolicy"`` is SB3's name for the policy of Dict observations (here the goal env's)
    policy_aliases = {"TabularGoalPolicy": TabularGoalPolicy, "MultiInputPolicy": TabularGoalPolicy}  # noqa: RUF012
    policy: TabularGoalPolicy

    def __init__(
        self,
        policy: str | type[TabularGoalPolicy],
        env: GymEnv | str,
        learning_rate: float = 0.1,
        gamma: float = 0.99,
        epsilon: float = 0.1,
        tau: float = 0.0,
        post_exploration: bool = True,
        post_exploration_rule: PostExplorationRule | dict[str, Any] | None = None,
        relabel_fraction: float = 0.5,
        policy_kwargs: dict[str, Any] | None = None,
        stats_window_size: int = 100,
        tensorboard_log: str | None = None,
        verbose: int = 0,
        seed: int | None = None,
        device: str = "cpu",
        _init_setup_model: bool = True,
    ) -> None:
        gamma = check_unit_interval("gamma", gamma)
        epsilon = check_unit_interval("epsilon", epsilon)
        relabel_fraction = check_unit_interval("relabel_fraction", relabel_fraction)
        check_step_size("learning_rate", learning_rate)  # Eq. 6.2's step size (RL-Zoo passes a schedule)
        tau = check_float("tau (Eq. 6.5; 0 = uniform)", tau, minimum=0.0)
        if isinstance(post_exploration_rule, dict):
            post_exploration_rule = make_post_exploration_rule(**post_exploration_rule)
        if post_exploration_rule is not None and not isinstance(post_exploration_rule, PostExplorationRule):
            raise TypeError(
                "post_exploration_rule must be a sb3_gcrl.post_exploration rule (FixedSteps, ProportionalSteps, "
                f"NoveltyAdaptive), got {type(post_exploration_rule).__name__}"
            )
        if env is not None:
            env = self._as_goal_env(env)
        super().__init__(
            policy,
            env,
            learning_rate=learning_rate,
            policy_kwargs=policy_kwargs,
            stats_window_size=check_int("stats_window_size", stats_window_size),
            tensorboard_log=tensorboard_log,
            verbose=verbose,
            device=device,
            support_multi_env=False,
            seed=seed,
            supported_action_spaces=(gym.spaces.Discrete,),
        )
        self.gamma = float(gamma)
        self.epsilon = float(epsilon)
        self.tau = float(tau)
        self.post_exploration = check_bool("post_exploration", post_exploration)
        self.post_exploration_rule = post_exploration_rule or ProportionalSteps(0.5)
        self.relabel_fraction = float(relabel_fraction)
        self.goal_space: BinnedGoalSpace | None = None
        #: goal commanded when :meth:`predict` gets a bare state of the plain env (the env's own task; None: unknown)
        self.task_goal: int | None = None
        if _init_setup_model:
            self._setup_model()

    @staticmethod
    def _as_goal_env(env: GymEnv | str) -> gym.Env:
        if isinstance(env, str):
            env = gym.make(env)
        if isinstance(env, DummyVecEnv) and env.num_envs == 1:
            env = env.envs[0]
        if not isinstance(env, gym.Env):
            raise TypeError(
                f"TabularIMGEP runs one env and decides its goals itself: pass a gymnasium env or env id, got "
                f"{type(env).__name__}"
            )
        if isinstance(env.observation_space, gym.spaces.Dict):
            goal_env = env
            while not isinstance(goal_env, TabularGoalEnv):
                if not isinstance(goal_env, gym.Wrapper):
                    raise TypeError(
                        "TabularIMGEP needs a tabular env (Discrete observation) or a sb3_gcrl.imgep.TabularGoalEnv"
                    )
                goal_env = goal_env.env
            return env
        return TabularGoalEnv(env, terminate_at_goal=False)

    def _setup_model(self) -> None:
        self._setup_lr_schedule()
        with self._continuing_saved_generator():  # a loaded model continues the saved one's draws
            self.set_random_seed(self.seed)
        self.policy = self.policy_class(  # type: ignore[assignment]
            self.observation_space, self.action_space, self.lr_schedule, **self.policy_kwargs
        )
        self.policy = self.policy.to(self.device)
        self._setup_runtime()

    def _setup_runtime(self) -> None:
        """Objects rebuilt at setup and after ``load``; goal space (visit counts), counters and generator are saved."""
        if self.env is not None:
            self.task_goal = self.goal_env.task_goal
        self._capacity = 1024
        self._alloc(self._capacity)
        if getattr(self, "goal_space", None) is None:  # loaded models keep their saved counts
            n_goals = self.observation_space["desired_goal"].n
            # Discrete goals are 1-wide bins of the shared binned goal space: bin index == goal index.
            self.goal_space = BinnedGoalSpace([0.0], [float(n_goals)], n_goals, within_bin="visited")
            self._n_episodes = 0
            self._n_reached = 0
            self._n_post_exploration_steps = 0

    def set_env(self, env: GymEnv | str, force_reset: bool = True) -> None:  # type: ignore[override]
        """The env to learn in: a plain tabular env (or id) is wrapped in a :class:`TabularGoalEnv` as in ``__init__``.

        :param env: the new env (its spaces must match the model's).
        :param force_reset: as in SB3.
        """
        super().set_env(self._as_goal_env(env), force_reset=force_reset)
        self.task_goal = self.goal_env.task_goal

    def predict(
        self,
        observation: np.ndarray | dict[str, np.ndarray],
        state: tuple[np.ndarray, ...] | None = None,
        episode_start: np.ndarray | None = None,
        deterministic: bool = False,
    ) -> tuple[np.ndarray, tuple[np.ndarray, ...] | None]:
        """Greedy action for a goal-conditioned observation, or for a bare state of the plain env.

        :param observation: a Dict observation of the :class:`TabularGoalEnv` (``observation`` and
            ``desired_goal``), or a state (an int or an array of ints) of the plain tabular env, in which case the
            goal of the env's own task (:attr:`task_goal`) is commanded.
        :param state: unused (no recurrent state).
        :param episode_start: unused.
        :param deterministic: unused (the greedy policy is deterministic).
        :return: the action(s) and None.
        :raises ValueError: a bare state but no task goal is known, or a state outside the env's states.
        """
        if not isinstance(observation, dict):
            observation = self._goal_observation(observation)
        return super().predict(observation, state, episode_start, deterministic)

    def _goal_observation(self, states: Any) -> dict[str, np.ndarray]:
        """The Dict observation commanding :attr:`task_goal` from bare states of the plain env."""
        if self.task_goal is None:
            raise ValueError(
                "TabularIMGEP's policy is goal-conditioned and got a bare state of the plain env, whose own task goal "
                "is unknown (only MiniGrid tasks have one, their goal tile). Pass Dict observations "
                "{'observation': s, 'desired_goal': g} (e.g. evaluate on sb3_gcrl.imgep.TabularGoalEnv(env)), or "
                "name the task's goal: TabularIMGEP(..., env=TabularGoalEnv(env, task_goal=g))."
            )
        n_states = self.observation_space["observation"].n  # type: ignore[index]
        states = np.asarray(states)
        if (
            not np.issubdtype(states.dtype, np.integer)
            or states.size == 0
            or not ((states >= 0) & (states < n_states)).all()
        ):
            raise ValueError(
                f"TabularIMGEP.predict takes a Dict observation or states of the plain env (integers in "
                f"[0, {n_states})), got {states!r}"
            )
        return {"observation": states, "desired_goal": np.full_like(states, self.task_goal)}

    @classmethod
    def load(cls, path: Any, env: GymEnv | str | None = None, **kwargs: Any) -> TabularIMGEP:  # type: ignore[override]
        """Load a saved agent; a plain tabular ``env`` is wrapped in a :class:`TabularGoalEnv` as in ``__init__``."""
        return super().load(path, env=None if env is None else cls._as_goal_env(env), **kwargs)

    def _alloc(self, capacity: int) -> None:
        self._states = np.zeros(capacity, dtype=np.int64)
        self._actions = np.zeros(capacity, dtype=np.int64)
        self._next_states = np.zeros(capacity, dtype=np.int64)
        self._next_goals = np.zeros(capacity, dtype=np.int64)
        self._terminals = np.zeros(capacity, dtype=bool)

    def _grow(self) -> None:
        old = (self._states, self._actions, self._next_states, self._next_goals, self._terminals)
        self._capacity *= 2
        self._alloc(self._capacity)
        for new, prev in zip((self._states, self._actions, self._next_states, self._next_goals, self._terminals), old):
            new[: prev.size] = prev

    @property
    def goal_env(self) -> TabularGoalEnv:
        """The :class:`TabularGoalEnv` the agent acts in."""
        env = self.env.envs[0]  # type: ignore[union-attr]
        while not isinstance(env, TabularGoalEnv):
            env = env.env
        return env

    # --- acting -------------------------------------------------------------------------------------------------
    def _explore_action(self, state: int, goal: int) -> int:
        """Epsilon-greedy with random tie-breaking (an all-zero row is a uniformly random action)."""
        n_actions = self.policy.n_actions
        if self._rng.random() < self.epsilon:
            return int(self._rng.integers(n_actions))
        q = self.policy.q[state, goal]
        best = np.flatnonzero(q == q.max())
        return int(best[0] if best.size == 1 else self._rng.choice(best))

    def _sample_goal(self) -> int | None:
        """Eq. 6.5 over the visited goals; None while the goal space is empty (random-policy episode)."""
        if self.goal_space.n_visited == 0:
            return None
        visited, p = self.goal_space.novelty_probabilities(self.tau)
        return int(self._rng.choice(visited, p=p))  # bin index == goal index

    # --- learning -----------------------------------------------------------------------------------------------
    def _hindsight_goals(self, length: int, reached_at: int | None, goal: int | None) -> np.ndarray:
        """Goals to learn from: the commanded one plus the relabeled states of Sec. 6.4.2."""
        budget = int(np.ceil(self.relabel_fraction * length))
        if reached_at is None:
            go_part, post_part = np.arange(length), np.arange(0)
        else:
            go_part, post_part = np.arange(reached_at + 1), np.arange(reached_at + 1, length)
        n_go = int(np.clip(budget - post_part.size, 0, go_part.size))
        picked = np.concatenate([post_part, self._rng.choice(go_part, size=n_go, replace=False)])
        goals = self._next_goals[picked.astype(np.int64)]
        if goal is not None:
            goals = np.append(goals, goal)
        return np.unique(goals)

    def _update(self, length: int, goals: np.ndarray) -> None:
        """Q-learning (Eq. 6.2) for every goal in ``goals`` over the episode, last transition first.

        Reaching the goal is terminal for that goal (its one-hot reward, Eq. 6.6, is the whole return); the env's
        own terminations (lava) are terminal for every goal; truncation bootstraps.
        """
        q = self.policy.q
        alpha, gamma = float(self.lr_schedule(self._current_progress_remaining)), self.gamma
        for t in range(length - 1, -1, -1):
            s, a, s2 = self._states[t], self._actions[t], self._next_states[t]
            hit = goals == self._next_goals[t]
            done = hit | self._terminals[t]
            target = hit + gamma * np.where(done, 0.0, q[s2, goals].max(axis=1))
            q[s, goals, a] += alpha * (target - q[s, goals, a])

    def _run_episode(self, callback: BaseCallback, total_timesteps: int) -> bool:
        env = self.goal_env
        goal = self._sample_goal()
        obs, _ = env.reset(options={"goal": goal} if goal is not None else None)
        state = int(obs["observation"])
        first_goal = int(obs["achieved_goal"])
        rule_counts = self.goal_space.counts
        reached_at: int | None = None
        post_left = 0
        t = 0
        while True:
            if t == self._capacity:
                self._grow()
            post_exploring = reached_at is not None
            if goal is None or post_exploring:
                action = int(self._rng.integers(self.policy.n_actions))  # random policy: init episode / post-expl.
            else:
                action = self._explore_action(state, goal)
            obs, reward, terminated, truncated, info = env.step(action)
            self.num_timesteps += 1
            next_state = int(obs["observation"])
            self._states[t], self._actions[t], self._next_states[t] = state, action, next_state
            self._next_goals[t], self._terminals[t] = obs["achieved_goal"], terminated
            t += 1
            state = next_state
            episode_over = bool(terminated or truncated)
            if post_exploring:
                self._n_post_exploration_steps += 1
                post_left -= 1
                episode_over = episode_over or post_left <= 0
            elif goal is not None and int(obs["achieved_goal"]) == goal:
                reached_at = t - 1
                self._n_reached += 1
                if not self.post_exploration:
                    episode_over = True
                else:
                    visited = rule_counts[rule_counts > 0]
                    median = float(np.median(visited))
                    post_left = self.post_exploration_rule.length(t, float(rule_counts[goal]), median)
                    episode_over = episode_over or post_left <= 0
            # the per-step locals SB3's off-policy loop gives callbacks, batched over the one env
            new_obs = {key: np.array([value]) for key, value in obs.items()}
            rewards = np.array([reward], dtype=np.float32)
            actions = np.array([action])
            dones = np.array([episode_over])
            infos = [info]
            callback.update_locals(locals())
            if not callback.on_step():
                return False
            if episode_over or self.num_timesteps >= total_timesteps:
                break
        # Algorithm 3: extend G and p(g) with every state of the episode, then learn with hindsight.
        self.goal_space.add(np.append(self._next_goals[:t], first_goal).astype(np.float64)[:, None])
        self._update(t, self._hindsight_goals(t, reached_at, goal))
        self._n_episodes += 1
        self.ep_info_buffer.append({"r": float(reached_at is not None), "l": t, "t": 0.0})  # type: ignore[union-attr]
        self.ep_success_buffer.append(reached_at is not None)  # type: ignore[union-attr]
        return True

    def learn(
        self: SelfTabularIMGEP,
        total_timesteps: int,
        callback: MaybeCallback = None,
        log_interval: int = 100,
        tb_log_name: str = "TabularIMGEP",
        reset_num_timesteps: bool = True,
        progress_bar: bool = False,
    ) -> SelfTabularIMGEP:
        """Run Algorithm 3 for ``total_timesteps`` environment steps (post-exploration steps included).

        :param log_interval: log every this many episodes.
        """
        total_timesteps, callback = self._setup_learn(
            total_timesteps, callback, reset_num_timesteps, tb_log_name, progress_bar
        )
        callback.on_training_start(locals(), globals())
        while self.num_timesteps < total_timesteps:
            callback.on_rollout_start()  # a rollout is one episode (goal, go, post-explore), then the table update
            keep_going = self._run_episode(callback, total_timesteps)
            callback.on_rollout_end()
            if not keep_going:
                break
            self._update_current_progress_remaining(self.num_timesteps, total_timesteps)
            if log_interval and self._n_episodes % log_interval == 0:
                self.dump_logs()
        callback.on_training_end()
        return self

    # --- metrics --------------------------------------------------------------------------------------------
    def visitation_entropy(self) -> float:
        """Entropy of the visits of the goal space so far (Eq. 6.7)."""
        return visitation_entropy(self.goal_space.counts)

    def coverage(self) -> float:
        """Fraction of the reachable goals visited so far."""
        mask = np.zeros(self.goal_space.n_cells, dtype=bool)
        mask[self.goal_env.reachable_goals] = True
        return coverage(self.goal_space.counts, mask)

    def make_all_goals_env(self) -> TabularGoalEnv:
        """A new :class:`TabularGoalEnv` on the registered env the agent learns in (its id and constructor kwargs,
        e.g. a MiniGrid layout seed), for the all-goals evaluation (Sec. 6.5.1).

        :raises ValueError: when the env was not made by ``gym.make`` (pass the evaluation env explicitly then).
        """
        return TabularGoalEnv(recreate_env(self.goal_env.unwrapped.spec, base_only=True))

    def dump_logs(self) -> None:
        """Write the IMGEP's log data (SB3's public hook): episodes, success, goal space, post-exploration."""
        self.logger.record("time/episodes", self._n_episodes, exclude="tensorboard")
        self.logger.record("rollout/ep_len_mean", safe_mean([ep["l"] for ep in self.ep_info_buffer]))
        self.logger.record("rollout/success_rate", safe_mean(list(self.ep_success_buffer)))
        self.logger.record("imgep/goal_space_size", self.goal_space.n_visited)
        self.logger.record("imgep/goals_reached", self._n_reached)
        self.logger.record("post_exploration/steps", self._n_post_exploration_steps)
        self.logger.record("post_exploration/coverage", self.coverage())
        self.logger.record("post_exploration/visitation_entropy", self.visitation_entropy())
        time_elapsed = max((time.time_ns() - self.start_time) / 1e9, sys.float_info.epsilon)
        self.logger.record("time/fps", int((self.num_timesteps - self._num_timesteps_at_start) / time_elapsed))
        self.logger.record("time/time_elapsed", int(time_elapsed), exclude="tensorboard")
        self.logger.record("time/total_timesteps", self.num_timesteps, exclude="tensorboard")
        self.logger.dump(step=self.num_timesteps)

    # --- saving ---------------------------------------------------------------------------------------------
    def _excluded_save_params(self) -> list[str]:
        return [
            *super()._excluded_save_params(),
            "_states",
            "_actions",
            "_next_states",
            "_next_goals",
            "_terminals",
        ]

    def _get_torch_save_params(self) -> tuple[list[str], list[str]]:
        return ["policy"], []
