"""Tests of the model-based MoReFree agent (thesis Ch. 3): world model, distance reward, goals, SB3 contracts."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from envs import MOREFREE_TINY_NET
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.morefree import MoReFree, SequenceReplayBuffer, morefree_go_explore
from sb3_gcrl.morefree.goals import AgentExploreAction, PEGScheduler, find_agent_hooks
from sb3_gcrl.morefree.networks import DynamicalDistance, WorldModel, frozen, lambda_returns, symlog
from sb3_gcrl.wrappers import ResetFreeWrapper

TINY = MOREFREE_TINY_NET
TINY_ALGO = {
    "learning_starts": 60,
    "batch_size": 4,
    "batch_length": 8,
    "train_ratio": 10,
    "imagination_horizon": 4,
    "imagination_starts": 16,
    "peg_candidates": 8,
    "policy_kwargs": TINY,
}


def tiny(env: Any, seed: int = 0, **overrides: Any) -> MoReFree:
    return MoReFree("MultiInputPolicy", env, seed=seed, **{**TINY_ALGO, **overrides})


# ------------------------------------------------------------------------------------------------- world model
def chain_sequences(rng: np.random.Generator, batch: int, length: int) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
    """A deterministic 1-D system x' = x + 0.5 a (state = [x, x]), random actions; time-major tensors."""
    x = rng.uniform(-1, 1, batch)
    states, actions = [], []
    prev = np.zeros(batch)
    for _ in range(length):
        states.append(np.stack([x, x], -1))
        actions.append(prev[:, None])
        prev = rng.uniform(-1, 1, batch)
        x = np.clip(x + 0.5 * prev, -2, 2)
    is_first = np.zeros((length, batch), dtype=bool)
    is_first[0] = True
    as_t = lambda a: th.as_tensor(np.asarray(a), dtype=th.float32)  # noqa: E731
    return as_t(states), as_t(actions), th.as_tensor(is_first)


def test_world_model_loss_falls_on_a_deterministic_system():
    th.manual_seed(0)
    rng = np.random.default_rng(0)
    model = WorldModel(
        obs_dim=2, goal_dim=1, action_dim=1, hidden=32, layers=1, embed_dim=32, deter=32, stoch=4, classes=4
    )
    optimizer = th.optim.Adam(model.parameters(), lr=3e-3)
    recon, kl = [], []
    for _ in range(60):
        loss, _, _, metrics = model.loss(*chain_sequences(rng, 16, 8))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        recon.append(metrics["recon_loss"])
        kl.append(metrics["kl"])
    # reconstruction falls far; the KL stays at or near its free-nats floor (1 nat)
    assert np.mean(recon[-10:]) < 0.2 * np.mean(recon[:10])
    assert np.mean(kl[-10:]) < 1.5


def test_imagined_rollouts_have_the_right_shapes_and_stay_finite():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0))
    model.learn(80)  # a few training steps
    states, actions, is_first = (th.as_tensor(a) for a in model.replay_buffer.sample(3, 8, model._rng))
    _, post, _, _ = model.policy.world_model.loss(states, actions, is_first)
    assert post.deter.shape == (8, 3, 16) and post.stoch.shape == (8, 3, 16)
    start = post.detach().flatten()
    goals = th.zeros(24, 1)
    with th.no_grad():
        feats, acts, entropies = model._imagine(lambda f: model.policy.actor_g.act(f, goals), start)
    horizon = model.imagination_horizon
    assert feats.shape == (horizon + 1, 24, model.policy.world_model.feat_dim)
    assert acts.shape == (horizon, 24, 1) and entropies.shape == (horizon, 24)
    assert th.isfinite(feats).all() and th.isfinite(acts).all() and (acts.abs() <= 1).all()
    # longer imagination than trained stays finite too
    model.imagination_horizon = 200
    with th.no_grad():
        feats, _, _ = model._imagine(model.policy.actor_e.act, start)
    assert th.isfinite(feats).all()


def test_lambda_returns_match_the_recursion():
    rewards = th.tensor([[1.0], [2.0]])
    values = th.tensor([[0.5], [1.5], [3.0]])
    gamma, lam = 0.9, 0.5
    last = 2.0 + gamma * 3.0
    first = 1.0 + gamma * ((1 - lam) * 1.5 + lam * last)
    np.testing.assert_allclose(lambda_returns(rewards, values, gamma, lam).squeeze(-1), [first, last], rtol=1e-6)


def test_pi_g_trained_in_imagination_reaches_goals_with_an_exact_distance_reward():
    """The imagination / lambda-return / dynamics-gradient path of MoReFree.train, with a known reward."""
    th.manual_seed(0)
    rng = np.random.default_rng(0)
    net = {**TINY, "deter": 32, "hidden": 32, "embed_dim": 32, "actor_hidden": 32}
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), policy_kwargs=net, imagination_horizon=8)
    policy, wm = model.policy, model.policy.world_model
    for group in (*policy.wm_optimizer.param_groups, *policy.actor_g_optimizer.param_groups):
        group["lr"] = 3e-3
    for _ in range(120):  # the model of x' = x + 0.5 a (state [x, x], goal x)
        loss, *_ = wm.loss(*chain_sequences(rng, 16, 8))
        model._step(policy.wm_optimizer, loss, wm.parameters())
    first = last = 0.0
    for step in range(150):
        with th.no_grad():
            _, post, _, _ = wm.loss(*chain_sequences(rng, 64, 2))
        goals = symlog(th.as_tensor(rng.uniform(-1.5, 1.5, (128, 1)), dtype=th.float32))
        with frozen(wm):
            feats, _, entropies = model._imagine(lambda f, g=goals: policy.actor_g.act(f, g), post.detach().flatten())
            distance = (wm.decode_goal(feats[1:]) - goals).abs().squeeze(-1)
            actor_loss, returns = model._actor_critic(feats, -distance, entropies, policy.critic_g_target, goals)
        model._step(policy.actor_g_optimizer, actor_loss, policy.actor_g.parameters())
        critic_loss = model._critic_loss(policy.critic_g, feats, returns, goals)
        model._step(policy.critic_g_optimizer, critic_loss, policy.critic_g.parameters())
        if step == 0:
            first = distance[-1].mean().item()
        last = distance[-1].mean().item()
    assert last < 0.4 * first, (first, last)


def imagined_final_distance(model: MoReFree, start: Any, goals: th.Tensor) -> float:
    """Mean |decoded achieved goal - goal| after ``imagination_horizon`` steps of the deterministic pi_G."""
    policy = model.policy
    with th.no_grad():
        feats, _, _ = model._imagine(lambda f: policy.actor_g.act(f, goals, deterministic=True), start)
        return (policy.world_model.decode_goal(feats[-1]) - goals).abs().mean().item()


def test_pi_g_learns_to_reach_goals_with_the_learned_distance_reward():
    """MoReFree's pi_G / distance step (imagined and replayed pairs, warm-up) on a learned model of x' = x + 0.5 a.

    With the distance trained on imagined pi_G pairs only and pi_G following it from the first update, pi_G
    drives every trajectory one way and the distance, never shown the way back, rewards it for that (final distance
    about 1.0 after 300 updates; the exact-distance reward gets 0.09).
    """
    th.manual_seed(0)
    rng = np.random.default_rng(0)
    net = {**TINY, "deter": 32, "hidden": 32, "embed_dim": 32, "actor_hidden": 32}
    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0)
    model = tiny(env, policy_kwargs=net, imagination_horizon=8, distance_warmup=100)
    policy, wm = model.policy, model.policy.world_model
    for optimizer in (policy.wm_optimizer, policy.actor_g_optimizer, policy.distance_optimizer):
        for group in optimizer.param_groups:
            group["lr"] = 3e-3
    for _ in range(120):  # the model of x' = x + 0.5 a (state [x, x], goal x)
        loss, *_ = wm.loss(*chain_sequences(rng, 16, 8))
        model._step(policy.wm_optimizer, loss, wm.parameters())
    with th.no_grad():
        _, post, _, _ = wm.loss(*chain_sequences(rng, 128, 2))
    test_start = post.flatten()
    test_goals = symlog(th.as_tensor(rng.uniform(-1.5, 1.5, (256, 1)), dtype=th.float32))
    before = imagined_final_distance(model, test_start, test_goals)
    for _ in range(300):
        states, actions, is_first = chain_sequences(rng, 16, 16)  # replayed random-action sequences
        with th.no_grad():
            _, replay_post, _, _ = wm.loss(states, actions, is_first)
            _, post, _, _ = wm.loss(*chain_sequences(rng, 64, 2))
        goals = symlog(th.as_tensor(rng.uniform(-1.5, 1.5, (128, 1)), dtype=th.float32))
        model._train_goal_policy(post.flatten(), goals, (replay_post.feat, symlog(states[..., -1:]), is_first))
        model._n_updates += 1
        if model._n_updates % model.target_update_interval == 0:
            policy.critic_g_target.load_state_dict(policy.critic_g.state_dict())
    after = imagined_final_distance(model, test_start, test_goals)
    assert after < 0.4 * before, (before, after)


def test_distance_loss_skips_pairs_across_a_physical_reset():
    th.manual_seed(0)
    net = DynamicalDistance(1, 1, hidden=8, layers=1)
    feats = th.zeros(4, 1, 1)
    goals = th.zeros(4, 1, 1)
    is_first = th.tensor([[True], [False], [True], [False]])
    with th.no_grad():
        th.nn.init.zeros_(net.net[-1].weight)
        th.nn.init.constant_(net.net[-1].bias, -20.0)  # predicts 0 everywhere
        # pairs inside segments [0, 1] and [2, 3] have targets 0 or 1/3 (horizon 3); across the reset they'd add 2/3, 1
        losses = [net.loss(feats, goals, 64, 0.0, th.Generator().manual_seed(s), 3, is_first) for s in range(20)]
        crossed = [net.loss(feats, goals, 64, 0.0, th.Generator().manual_seed(s), 3) for s in range(20)]
    assert max(loss.item() for loss in losses) <= (1 / 3) ** 2 + 1e-6
    assert max(loss.item() for loss in crossed) > (1 / 3) ** 2 + 1e-3


# ------------------------------------------------------------------------------------------------- distance
def test_distance_network_orders_states_on_a_chain():
    th.manual_seed(0)
    n_states, steps = 10, 10
    one_hot = th.eye(n_states)
    positions = th.arange(n_states, dtype=th.float32).unsqueeze(-1) / n_states
    # trajectories walking up the chain from random starts (clipped at the end)
    starts = th.randint(0, n_states, (64,))
    index = (starts.unsqueeze(0) + th.arange(steps).unsqueeze(-1)).clamp(max=n_states - 1)  # (T, N)
    feats, goals = one_hot[index], positions[index]
    net = DynamicalDistance(n_states, 1, hidden=32, layers=2)
    optimizer = th.optim.Adam(net.parameters(), lr=3e-3)
    generator = th.Generator().manual_seed(0)
    for _ in range(400):
        loss = net.loss(feats, goals, n_pairs=256, neg_fraction=0.0, generator=generator)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with th.no_grad():
        from_start = net(one_hot[0].expand(n_states, -1), positions).numpy()
    # farther states along the chain are predicted farther away
    assert (np.diff(from_start[: n_states - 1]) > 0).all(), from_start


# ------------------------------------------------------------------------------------------------- goals
def test_imagination_goal_proportions_match_alpha():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), imagination_alpha=0.3)
    model.learn(30)  # fills the buffer (no training yet)
    n = 20_000
    goals, kinds = model.sample_imagination_goals(n)
    for kind, p in ((0, 0.15), (1, 0.15), (2, 0.7)):
        share = np.mean(kinds == kind)
        assert abs(share - p) < 4 * np.sqrt(p * (1 - p) / n), (kind, share)
    env = model.get_env().envs[0].unwrapped
    np.testing.assert_allclose(goals[kinds == 0], env.start_height)  # rho_0
    np.testing.assert_allclose(goals[kinds == 1], env.goal)  # rho_g*
    stored = model.replay_buffer.states[0, : model.replay_buffer.pos[0], -1]
    assert np.isin(goals[kinds == 2, 0], stored).all()  # replayed achieved goals
    # uniform over the buffer: every stored state is drawn about equally often
    draws = model.replay_buffer.sample_states(30_000, np.random.default_rng(1))
    rows = model.replay_buffer.pos[0]
    counts = np.bincount(np.searchsorted(np.sort(stored), draws[:, -1]), minlength=rows)
    assert counts.min() > 0


def test_alpha_is_read_from_the_env_scheduler():
    def make(env: gym.Env) -> gym.Env:
        return morefree_go_explore(ResetFreeWrapper(env, eval_horizon=20), alpha=0.0)

    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0, wrapper_class=make))
    model.learn(20, callback=ResetFreeCallback())
    assert model._alpha == 0.0
    _, kinds = model.sample_imagination_goals(500)
    assert (kinds == 2).all()  # reset-free PEG: replayed goals only


def test_sequence_buffer_chunks_never_cross_the_write_position():
    buffer = SequenceReplayBuffer(capacity=10, n_envs=1, state_dim=1, action_dim=1, goal_dim=1)
    for t in range(23):  # wraps twice; rows hold t = 13..22
        buffer.add(0, np.array([t], dtype=np.float32), None if t == 0 else np.zeros(1))
    states, _, is_first = buffer.sample(200, 4, np.random.default_rng(0))
    values = states[..., 0]
    assert (np.diff(values, axis=0) == 1).all() and values.min() >= 13
    assert is_first[0].all() and not is_first[1:].any()


def test_sequence_buffer_lists_achieved_goals_in_storage_order_for_visitation_heatmaps():
    buffer = SequenceReplayBuffer(capacity=10, n_envs=2, state_dim=3, action_dim=1, goal_dim=2)
    for t in range(8):  # env 0 wraps (5 rows, holds t = 3..7), env 1 holds t = 0..2
        buffer.add(0, np.array([-1, t, 10 * t], dtype=np.float32), None)
        if t < 3:
            buffer.add(1, np.array([-1, 100 + t, 0], dtype=np.float32), None)
    goals = buffer.achieved_goals()
    assert goals.shape == (buffer.size(), 2) == (8, 2)
    np.testing.assert_array_equal(goals[:, 0], [3, 4, 5, 6, 7, 100, 101, 102])
    np.testing.assert_array_equal(goals[:5, 1], [30, 40, 50, 60, 70])
    with pytest.raises(ValueError, match="goal_dim"):
        SequenceReplayBuffer(capacity=10, n_envs=1, state_dim=3, action_dim=1, goal_dim=4)


# ------------------------------------------------------------------------------------------------- no env reward
class RewardlessGoalEnv(gym.Wrapper):
    """A goal env whose reward is NaN and whose compute_reward raises: training must not need either."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        self.compute_reward_calls = 0

    def step(self, action: np.ndarray) -> Any:
        obs, _, terminated, truncated, info = self.env.step(action)
        return obs, float("nan"), terminated, truncated, info

    def compute_reward(self, *args: Any) -> Any:
        self.compute_reward_calls += 1
        raise AssertionError("the env's reward must not be used for training")


def test_training_never_reads_the_environment_reward():
    env = make_vec_env(lambda: RewardlessGoalEnv(gym.make("GCRL/GrowingTreeGoal-v0")), n_envs=1, seed=0)
    model = tiny(env)
    model.learn(300)
    assert model._n_updates > 10
    for name, value in model.get_parameters()["policy"].items():
        assert th.isfinite(value).all(), name
    assert env.envs[0].get_wrapper_attr("compute_reward_calls") == 0


# ------------------------------------------------------------------------------------------------- SB3 contracts
def test_save_load_gives_identical_actions_and_restores_the_world_model(tmp_path: Path):
    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0)
    model = tiny(env)
    model.learn(150)
    obs = env.reset()
    expected, _ = model.predict(obs, deterministic=True)
    model.save(tmp_path / "morefree.zip")
    loaded = MoReFree.load(tmp_path / "morefree.zip", env=env)
    np.testing.assert_array_equal(loaded.predict(obs, deterministic=True)[0], expected)
    for key, value in model.policy.world_model.state_dict().items():
        assert th.equal(value, loaded.policy.world_model.state_dict()[key]), key
    assert loaded.policy.wm_optimizer.state_dict()["state"], "world-model optimizer state restored"
    assert loaded._n_updates == model._n_updates
    loaded.learn(40, reset_num_timesteps=False)  # the empty buffer refills before training resumes


def test_predict_filters_the_latent_across_an_episode_with_episode_start():
    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=2, seed=0)
    model = tiny(env)
    obs = env.reset()
    first, _ = model.predict(obs, episode_start=np.ones(2, bool), deterministic=True)
    model.policy.predict_burn_in = 1
    memoryless, _ = model.predict(obs, deterministic=True)
    np.testing.assert_allclose(first, memoryless, atol=1e-6)  # a start is the one-step memoryless latent
    model.predict(obs, episode_start=np.zeros(2, bool), deterministic=True)  # carries the latent on
    mean, _ = evaluate_policy(model, Monitor(gym.make("GCRL/GrowingTreeGoal-v0")), n_eval_episodes=1)
    assert np.isfinite(mean)


def test_memoryless_predict_holds_the_observation_for_the_burn_in_steps():
    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=2, seed=0)
    model = tiny(env, policy_kwargs={**TINY, "predict_burn_in": 3})
    policy = model.policy
    obs = env.reset()
    memoryless, _ = model.predict(obs, deterministic=True)
    # the same as an episode that starts at this observation and stays there with zero actions for 3 steps
    for step in range(3):
        start = np.full(2, step == 0)
        policy._eval_action = th.zeros(2, 1)  # zero previous action
        held, _ = model.predict(obs, episode_start=start, deterministic=True)
    np.testing.assert_allclose(memoryless, held, atol=1e-6)
    with pytest.raises(ValueError, match="predict_burn_in"):
        tiny(env, policy_kwargs={**TINY, "predict_burn_in": 0})


def test_invalid_spaces_and_hyperparameters_are_refused():
    with pytest.raises(TypeError, match="goal env"):
        MoReFree("MultiInputPolicy", "Pendulum-v1")
    with pytest.raises(ValueError, match="train_ratio"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", train_ratio=0)
    with pytest.raises(ValueError, match="imagination_alpha"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", imagination_alpha=1.5)
    with pytest.raises(ValueError, match="distance_warmup"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", distance_warmup=-1)
    with pytest.raises(TypeError, match="distance_on_replay"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", distance_on_replay="yes")
    with pytest.raises(ValueError, match="exploratory"):
        morefree_go_explore(ResetFreeWrapper(gym.make("GCRL/GrowingTreeGoal-v0"), eval_horizon=20), exploratory="x")


def test_device_cuda_when_available():
    if not th.cuda.is_available():
        pytest.skip("no CUDA device on this machine (the device check runs where one is lent)")
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), device="cuda")
    model.learn(100)
    assert next(model.policy.parameters()).is_cuda


# ------------------------------------------------------------------------------------------------- reset-free
def reset_free_env(alpha: float = 0.2, eval_horizon: int = 40) -> Any:
    def make(env: gym.Env) -> gym.Env:
        return morefree_go_explore(
            ResetFreeWrapper(env, hard_reset_every=100_000, eval_horizon=eval_horizon),
            alpha=alpha,
            scheduler_kwargs={"goal_low": [-2.0], "goal_high": [2.0], "n_bins": 8},
        )

    return make


def test_reset_free_training_with_peg_goals_and_the_agents_explore_phase():
    make = reset_free_env()
    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0, wrapper_class=make)
    model = tiny(env)
    model.learn(400, callback=ResetFreeCallback())
    wrapper = env.envs[0]
    peg, slot = find_agent_hooks(wrapper)
    assert isinstance(peg, PEGScheduler) and isinstance(slot, AgentExploreAction)
    assert wrapper.get_wrapper_attr("interventions") == 1  # one physical reset in 400 steps
    assert peg.n_planned > 0 and peg.n_fallback > 0  # novelty until learning starts, PEG after
    assert slot.n_agent > 0  # Explore phases executed pi_E's actions
    counts = wrapper.get_wrapper_attr("goal_counts")
    assert counts.get("explore", 0) > 0
    # one continuous stream: only the first row is a start
    buffer = model.replay_buffer
    assert buffer.is_first[0, : buffer.pos[0]].sum() == 1
    assert peg.agent is None  # detached after learn (not pickled with the env)
    # evaluation stays episodic: an eval env with the same wrapper, never switched
    eval_env = Monitor(make(gym.make("GCRL/GrowingTreeGoal-v0")))
    _, lengths = evaluate_policy(model, eval_env, n_eval_episodes=2, return_episode_rewards=True)
    assert lengths == [40, 40]


def test_executed_explore_actions_are_stored_with_a_random_explorer():
    def make(env: gym.Env) -> gym.Env:
        return morefree_go_explore(
            ResetFreeWrapper(env, eval_horizon=20), alpha=0.2, explorer="random", exploratory="novelty"
        )

    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0, wrapper_class=make)
    model = tiny(env, learning_starts=10_000)
    model.learn(60, callback=ResetFreeCallback())
    buffer = model.replay_buffer
    rows = buffer.pos[0]
    heights = buffer.states[0, :rows, 0]
    actions = buffer.actions[0, 1:rows, 0]
    # GrowingTree: height += action (scaled to [-0.1, 0.1]); the stored action explains every step
    moved = np.diff(heights)
    np.testing.assert_allclose(moved, np.clip(actions * 0.1, -2 - heights[:-1], 2 - heights[:-1]), atol=1e-5)


#: thesis Table 3.2 train ratios
TRAIN_RATIO = {
    "pointumaze": 2,
    "sawyer_door": 5,
    "tabletop": 1,
    "fetch_push": 2,
    "fetch_pick_and_place": 2,
    "fetch_push_hard": 2,
    "fetch_pick_and_place_hard": 2,
    "ant": 2,
}
#: exploration alpha (env) and imagination alpha of each method
METHOD_ALPHAS = {"morefree": (0.2, 0.2), "peg": (0.0, 0.0), "wo_bf": (0.0, 0.2), "wo_imag": (0.2, 0.0)}


def test_zoo_configs_cover_every_task_method_and_preset():
    import yaml

    root = Path(__file__).resolve().parents[1] / "zoo_configs"
    seen = set()
    for path in sorted(root.glob("morefree_*.yml")):
        stem = path.stem.removeprefix("morefree_")
        task, method, preset = next(
            (t, m, stem[len(t) + len(m) + 2 :])
            for t in sorted(TRAIN_RATIO, key=len, reverse=True)
            for m in METHOD_ALPHAS
            if stem.startswith(f"{t}_{m}_")
        )
        seen.add((task, method, preset))
        ((_, hyperparams),) = yaml.safe_load(path.read_text()).items()
        assert hyperparams["train_ratio"] == TRAIN_RATIO[task], path.name
        assert any("ResetFreeCallback" in str(c) for c in hyperparams["callback"]), path.name
        (go_explore,) = (w for w in hyperparams["env_wrapper"] if "sb3_gcrl.morefree.morefree_go_explore" in w)
        env_alpha, imagination_alpha = METHOD_ALPHAS[method]
        assert go_explore["sb3_gcrl.morefree.morefree_go_explore"]["alpha"] == env_alpha, path.name
        assert hyperparams.get("imagination_alpha", env_alpha) == imagination_alpha, path.name
    for task in TRAIN_RATIO:
        for preset in ("cpu", "thesis"):
            assert {(task, "morefree", preset), (task, "peg", preset)} <= seen, (task, preset)
    for task in ("pointumaze", "fetch_push_hard", "fetch_pick_and_place_hard", "ant"):
        assert {(task, m, "cpu") for m in METHOD_ALPHAS} <= seen, task


@pytest.mark.parametrize("method", sorted(METHOD_ALPHAS))
def test_pointumaze_cpu_configs_train_with_the_alphas_they_state(method: str):
    import yaml
    from rl_zoo3.utils import get_wrapper_class

    path = Path(__file__).resolve().parents[1] / "zoo_configs" / f"morefree_pointumaze_{method}_cpu.yml"
    ((env_id, hyperparams),) = yaml.safe_load(path.read_text()).items()
    wrapper = get_wrapper_class(hyperparams)
    env = make_vec_env(env_id, n_envs=1, seed=0, wrapper_class=wrapper)
    kwargs = {k: v for k, v in hyperparams.items() if k not in ("n_timesteps", "policy", "env_wrapper", "callback")}
    kwargs.update(TINY_ALGO, policy_kwargs=TINY)  # tiny networks, same method settings
    model = MoReFree("MultiInputPolicy", env, seed=0, **kwargs)
    model.learn(80, callback=ResetFreeCallback())
    assert model._alpha == METHOD_ALPHAS[method][1]
    assert env.envs[0].get_wrapper_attr("task_goal_alpha") == METHOD_ALPHAS[method][0]


def test_learn_stops_at_total_timesteps_whatever_the_train_ratio():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), train_ratio=1000)
    model.learn(50)
    assert model.num_timesteps == 50


@pytest.mark.filterwarnings("ignore:The environment is already wrapped")
def test_subprocess_envs_with_the_agents_hooks_are_refused_and_vec_wrappers_are_seen_through():
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecMonitor

    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0, wrapper_class=reset_free_env(eval_horizon=20))
    model = tiny(VecMonitor(env))
    model.learn(200, callback=ResetFreeCallback())
    peg, slot = find_agent_hooks(env.envs[0])
    assert peg is not None and peg.n_planned > 0 and slot is not None and slot.n_agent > 0
    subprocess = make_vec_env(
        "GCRL/GrowingTreeGoal-v0",
        n_envs=1,
        seed=0,
        wrapper_class=reset_free_env(eval_horizon=20),
        vec_env_cls=SubprocVecEnv,
    )
    try:
        with pytest.raises(TypeError, match="DummyVecEnv"):
            tiny(subprocess).learn(10, callback=ResetFreeCallback())
    finally:
        subprocess.close()
