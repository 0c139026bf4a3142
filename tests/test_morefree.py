"""Tests of the model-based MoReFree agent (thesis Ch. 3): world model, distance reward, goals, SB3 contracts."""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import pytest
import torch as th
from envs import MOREFREE_TINY_NET
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.env_util import make_vec_env
from stable_baselines3.common.evaluation import evaluate_policy
from stable_baselines3.common.monitor import Monitor
from torch.distributions import Normal

import sb3_gcrl  # noqa: F401  (registers the GCRL/ envs)
from sb3_gcrl.callbacks import ResetFreeCallback
from sb3_gcrl.envs.growing_tree import GrowingTreeGoalEnv
from sb3_gcrl.morefree import MoReFree, SequenceReplayBuffer, losses, morefree_go_explore, peg
from sb3_gcrl.morefree.functional import frozen, lambda_returns, symexp, symlog
from sb3_gcrl.morefree.goals import PEGScheduler
from sb3_gcrl.morefree.networks import (
    RSSM,
    DisagreementEnsemble,
    DynamicalDistance,
    LatentState,
    TruncatedNormal,
    WorldModel,
)
from sb3_gcrl.wrappers import GOAL_REQUEST_KEY, GoExploreWrapper, ResetFreeWrapper

TINY = MOREFREE_TINY_NET
TINY_ALGO = {
    "learning_starts": 60,
    "batch_size": 4,
    "batch_length": 8,
    "train_ratio": 10,
    "imagination_horizon": 4,
    "imagination_starts": 16,
    "peg_samples": 8,
    "peg_iterations": 2,
    "compile_train_step": False,  # compiling takes minutes (test_compiled_train_step_matches_the_eager_one)
    "policy_kwargs": TINY,
}


def tiny(env: Any, seed: int = 0, **overrides: Any) -> MoReFree:
    return MoReFree("MultiInputPolicy", env, seed=seed, **{**TINY_ALGO, **overrides})


class ExplorerCheck(BaseCallback):
    """Checks, at every step, that the env executed the agent's action in each Explore-phase step and that the agent
    chose it as an Explore-phase action (pi_E once learning started); counts those steps after learning starts."""

    def __init__(self) -> None:
        super().__init__()
        self.phases: list[str] = []
        self.explore_steps = 0
        self.explorer_steps = 0

    def _on_training_start(self) -> None:
        read = self.model._phases

        def recorded() -> list[str]:
            self.phases = read()
            return self.phases

        self.model._phases = recorded  # type: ignore[method-assign]

    def _on_step(self) -> bool:
        for i, info in enumerate(self.locals["infos"]):
            if "executed_action" not in info:
                continue
            self.explore_steps += 1
            assert self.phases[i] == "explore"
            np.testing.assert_array_equal(info["executed_action"], self.locals["actions"][i])
            if self.num_timesteps > self.model.learning_starts:
                self.explorer_steps += 1
        return True


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
    model = WorldModel(obs_dim=2, goal_dim=1, action_dim=1, hidden=32, layers=2, deter=32, stoch=4, rssm_hidden=32)
    optimizer = th.optim.Adam(model.parameters(), lr=3e-3)
    recon, kl = [], []
    for _ in range(60):
        loss, _, metrics = model.loss(*chain_sequences(rng, 16, 8))
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
        recon.append(metrics["recon_loss"].item())
        kl.append(metrics["kl"].item())
    # reconstruction falls far; the KL stays at or near its free-nats floor (1 nat)
    assert np.mean(recon[-10:]) < 0.2 * np.mean(recon[:10])
    assert np.mean(kl[-10:]) < 1.5


def test_gaussian_kl_and_free_nats_on_the_average_match_a_hand_computation():
    rssm = RSSM(action_dim=1, embed_dim=4, deter=4, stoch=3, hidden=4)
    mean_q, std_q = th.tensor([[0.5, -1.0, 0.0]]), th.tensor([[0.5, 1.0, 2.0]])
    mean_p, std_p = th.tensor([[0.0, 0.0, 1.0]]), th.tensor([[1.0, 2.0, 1.0]])
    expected = th.distributions.kl_divergence(Normal(mean_q, std_q), Normal(mean_p, std_p)).sum(-1)
    th.testing.assert_close(rssm.kl(mean_q, std_q, mean_p, std_p), expected)
    post = LatentState(th.zeros(1, 4), mean_q, mean_q, std_q)
    loss, value = rssm.kl_loss(post, (mean_p, std_p), balance=0.8, free_nats=1.0)
    th.testing.assert_close(value, expected.mean())
    th.testing.assert_close(loss, expected.mean().clamp(min=1.0))  # both terms equal in value: 0.8 x + 0.2 x
    small, _ = rssm.kl_loss(post, (mean_q, std_q), balance=0.8, free_nats=1.0)
    assert small.item() == pytest.approx(1.0)  # a KL of 0 on average is lifted to the free nats


def test_truncated_normal_stays_in_bounds_with_the_truncated_entropy_and_reparameterised_gradients():
    from scipy.stats import truncnorm

    loc = th.tensor([0.0, 0.9, -0.99, 0.3], requires_grad=True)
    scale = th.tensor([1.0, 0.1, 0.5, 2.0], requires_grad=True)
    dist = TruncatedNormal(loc, scale)
    expected = [
        truncnorm((-1 - m) / s, (1 - m) / s, loc=m, scale=s).entropy()
        for m, s in zip([0, 0.9, -0.99, 0.3], [1, 0.1, 0.5, 2])
    ]
    np.testing.assert_allclose(dist.entropy().detach().numpy(), expected, rtol=1e-4, atol=1e-5)
    th.manual_seed(0)
    samples = th.stack([TruncatedNormal(loc, scale).rsample() for _ in range(4000)])
    assert (samples.abs() < 1).all()
    means = [
        truncnorm((-1 - m) / s, (1 - m) / s, loc=m, scale=s).mean()
        for m, s in zip([0, 0.9, -0.99, 0.3], [1, 0.1, 0.5, 2])
    ]
    np.testing.assert_allclose(samples.mean(0).detach().numpy(), means, atol=0.03)
    samples.mean(0).sum().backward()
    assert loc.grad is not None and (loc.grad > 0).all() and th.isfinite(scale.grad).all()
    assert th.equal(dist.mode, loc)


def test_the_batched_ensemble_is_its_members_applied_one_by_one():
    th.manual_seed(0)
    ensemble = DisagreementEnsemble(feat_dim=5, action_dim=2, target_dim=3, size=4, hidden=8, layers=2)
    feat, action = th.randn(7, 5), th.randn(7, 2)
    x = th.cat([feat, action], -1)
    members = []
    for k in range(4):
        h = x
        for depth, layer in enumerate(ensemble.layers):
            h = h @ layer.weight[k] + layer.bias[k, 0]
            h = th.nn.functional.elu(h) if depth < len(ensemble.layers) - 1 else h
        members.append(h)
    predictions = th.stack(members)
    th.testing.assert_close(ensemble(feat, action), predictions)
    th.testing.assert_close(ensemble.disagreement(feat, action), predictions.std(0).mean(-1))
    target = th.randn(7, 3)
    th.testing.assert_close(ensemble.loss(feat, action, target), 0.5 * (predictions - target).pow(2).sum(-1).mean())


def test_imagined_rollouts_have_the_right_shapes_and_stay_finite():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0))
    model.learn(80)  # a few training steps
    states, actions, is_first = (th.as_tensor(a) for a in model.replay_buffer.sample(3, 8, model._rng))
    _, post, _ = model.policy.world_model.loss(states, actions, is_first)
    assert post.deter.shape == (8, 3, TINY["deter"]) and post.stoch.shape == (8, 3, TINY["stoch"])
    start = post.detach().flatten()
    goals = th.zeros(24, 1)
    with th.no_grad():
        feats, acts, entropies = model.imagine(start, goals)
    horizon = model.imagination_horizon
    assert feats.shape == (horizon + 1, 48, model.policy.world_model.feat_dim)  # pi_G rows, then pi_E rows
    assert acts.shape == (horizon, 48, 1) and entropies.shape == (horizon, 48)
    assert th.isfinite(feats).all() and th.isfinite(acts).all() and (acts.abs() <= 1).all()
    th.testing.assert_close(feats[0, :24], feats[0, 24:])  # both policies start from the same states
    # longer imagination than trained stays finite too
    model.imagination_horizon = 200
    with th.no_grad():
        feats, _, _ = model.imagine(start, goals)
    assert th.isfinite(feats).all()


def test_lambda_returns_match_the_recursion():
    rewards = th.tensor([[1.0], [2.0]])
    values = th.tensor([[0.5], [1.5], [3.0]])
    gamma, lam = 0.9, 0.5
    last = 2.0 + gamma * 3.0
    first = 1.0 + gamma * ((1 - lam) * 1.5 + lam * last)
    np.testing.assert_allclose(lambda_returns(rewards, values, gamma, lam).squeeze(-1), [first, last], rtol=1e-6)


def chain_model(**overrides: Any) -> tuple[MoReFree, np.random.Generator]:
    """A tiny agent whose world model has learned x' = x + 0.5 a (state [x, x], goal x)."""
    th.manual_seed(0)
    rng = np.random.default_rng(0)
    net = {**TINY, "deter": 32, "rssm_hidden": 32, "model_hidden": 32, "head_hidden": 32, "actor_lr": 3e-3}
    model = tiny(
        make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0),
        policy_kwargs=net,
        imagination_horizon=8,
        **overrides,
    )
    policy, wm = model.policy, model.policy.world_model
    for group in policy.wm_optimizer.param_groups:
        group["lr"] = 3e-3
    for _ in range(150):
        loss, *_ = wm.loss(*chain_sequences(rng, 16, 8))
        model._apply(loss, ("wm",))
    return model, rng


def chain_starts(model: MoReFree, rng: np.random.Generator, n: int) -> LatentState:
    with th.no_grad():
        _, post, _ = model.policy.world_model.loss(*chain_sequences(rng, n, 2))
    return post.flatten()


def imagined_final_distance(model: MoReFree, start: LatentState, goals: th.Tensor) -> float:
    """Mean |decoded achieved goal - goal| after ``imagination_horizon`` steps of the deterministic pi_G."""
    policy, rssm = model.policy, model.policy.world_model.rssm
    with th.no_grad():
        latent = start
        for _ in range(model.imagination_horizon):
            latent = rssm.img_step(latent, policy.actor_g.act(latent.feat, goals, deterministic=True)[0])
        return (policy.world_model.decode_goal(latent.feat) - goals).abs().mean().item()


def test_pi_g_trained_in_imagination_reaches_goals_with_an_exact_distance_reward():
    """The imagination / lambda-return / dynamics-gradient path of MoReFree.train, with a known reward."""
    model, rng = chain_model()
    policy, wm = model.policy, model.policy.world_model
    test_start = chain_starts(model, rng, 64)
    test_goals = symlog(th.as_tensor(rng.uniform(-1.5, 1.5, (128, 1)), dtype=th.float32))
    before = imagined_final_distance(model, test_start, test_goals)
    for _ in range(150):
        start = chain_starts(model, rng, 64)
        goals = symlog(th.as_tensor(rng.uniform(-1.5, 1.5, (128, 1)), dtype=th.float32))
        with frozen(wm):
            feats, _, entropies = model.imagine(start, goals)
            feats_g = feats[:, :128]
            rewards = -(wm.decode_goal(feats_g[1:]) - goals).abs().squeeze(-1)
            returns = model.lambda_returns(feats_g, rewards, policy.critic_g_target, goals)
            actor_loss = losses.actor_loss(returns, entropies[:, :128], model.gamma, model.entropy_coef)
        critic_loss = losses.critic_loss(policy.critic_g, feats_g, returns, goals, model.gamma)
        model._apply(actor_loss + critic_loss, ("actor_g", "critic_g"))
    after = imagined_final_distance(model, test_start, test_goals)
    assert after < 0.4 * before, (before, after)


def test_pi_g_learns_to_reach_goals_with_the_learned_distance_reward():
    """MoReFree's imagination and learner losses (pi_G, critics, D on imagined and replayed pairs) on a learned model
    of x' = x + 0.5 a: pi_G comes to reach the commanded goals with the reward of the distance it learns.

    pi_G waits ``distance_warmup`` updates for D: started at once, it follows the young distance's slopes into one
    saturated action for every goal within 50 updates and, at this budget, ends farther from its goals than it began.
    """
    model, rng = chain_model(distance_warmup=300, distance_window=16)
    policy = model.policy
    for group in policy.distance_optimizer.param_groups:
        group["lr"] = 3e-3
    test_start = chain_starts(model, rng, 64)
    test_goals = symlog(th.as_tensor(rng.uniform(-1.5, 1.5, (128, 1)), dtype=th.float32))
    before = imagined_final_distance(model, test_start, test_goals)
    for _ in range(650):
        states = chain_sequences(rng, 16, 17)[0]  # replayed random-action streams: pairs up to 16 steps apart
        i = th.as_tensor(rng.integers(0, 17, 256))
        j = th.minimum(i + th.as_tensor(rng.integers(0, 17, 256)), th.tensor(16))
        column = th.as_tensor(rng.integers(0, 16, 256))
        replay = (symlog(states[i, column, -1:]), symlog(states[j, column, -1:]), j - i, th.ones(256))
        start = chain_starts(model, rng, 64)
        goals = symlog(th.as_tensor(rng.uniform(-1.5, 1.5, (128, 1)), dtype=th.float32))
        with frozen(policy.world_model, policy.distance, policy.ensemble):
            actor_loss, imagined, _ = model._imagination_losses(start, goals)
        learner_loss, _ = model._learner_losses(imagined, goals, th.arange(128), replay)
        skip = ("actor_g",) if model._n_updates < model.distance_warmup else ()
        model._apply(actor_loss + learner_loss, ("actor_g", "critic_g", "actor_e", "critic_e", "distance"), skip)
        model._n_updates += 1
        if model._n_updates % model.target_update_interval == 0:
            policy.critic_g_target.load_state_dict(policy.critic_g.state_dict())
    after = imagined_final_distance(model, test_start, test_goals)
    assert after < 0.6 * before, (before, after)


# ------------------------------------------------------------------------------------------------- distance
def test_replayed_distance_pairs_never_cross_a_physical_reset_or_the_write_position():
    buffer = SequenceReplayBuffer(capacity=40, n_envs=2, state_dim=2, action_dim=1, goal_dim=1)
    for t in range(30):  # env 0: a physical reset at t = 10 and 20; env 1 wraps its ring of 20 rows
        buffer.add(0, np.array([0, t], dtype=np.float32), None if t % 10 == 0 else np.zeros(1))
        buffer.add(1, np.array([1, 100 + t], dtype=np.float32), None if t == 0 else np.zeros(1))
    first, later, gaps, valid = buffer.sample_pairs(5000, 8, np.random.default_rng(0))
    assert valid.mean() > 0.5 and not valid.all()
    f, lt, g = first[valid, 0], later[valid, 0], gaps[valid]
    np.testing.assert_array_equal(lt - f, g)  # the values count the steps: every valid pair is in storage order
    assert ((f // 10 == lt // 10) | (f >= 100)).all()  # never across env 0's resets
    assert (f[f >= 100] >= 110).all()  # env 1's ring holds t = 10..29 only
    assert set(np.unique(g)) == set(range(9))


def test_distance_network_orders_points_on_a_chain():
    th.manual_seed(0)
    n_points, steps = 10, 10
    positions = th.arange(n_points, dtype=th.float32).unsqueeze(-1) / n_points
    # trajectories walking up the chain from random starts (clipped at the end)
    starts = th.randint(0, n_points, (64,))
    index = (starts.unsqueeze(0) + th.arange(steps).unsqueeze(-1)).clamp(max=n_points - 1)  # (T, N)
    net = DynamicalDistance(1, hidden=32, layers=2)
    optimizer = th.optim.Adam(net.parameters(), lr=3e-3)
    for _ in range(400):
        loss = net.trajectory_loss(positions[index], n_pairs=256, unit=steps)
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    with th.no_grad():
        from_start = net(positions[0].expand(n_points, -1), positions).numpy()
    # farther points along the chain are predicted farther away
    assert (np.diff(from_start[: n_points - 1]) > 0).all(), from_start


def test_distance_negatives_are_trained_beyond_the_longest_positive():
    th.manual_seed(0)
    net = DynamicalDistance(1, hidden=8, layers=1)
    with th.no_grad():
        th.nn.init.zeros_(net.net[-1].weight)
        th.nn.init.zeros_(net.net[-1].bias)  # predicts 0 everywhere
    goals = th.zeros(4, 6, 1)
    groups = th.tensor([0, 0, 0, 1, 1, 1])
    positives = net.trajectory_loss(goals, 4000, unit=3.0)
    with_negatives = net.trajectory_loss(goals, 4000, unit=3.0, neg_fraction=1.0, groups=groups)
    # positives: targets (j - i) / 3 for i <= j < 4; negatives (other group): target (3 + 1) / 3
    pairs = [(j - i) / 3 for i in range(4) for j in range(i, 4)]
    assert positives.item() == pytest.approx(np.mean(np.square(pairs)), rel=0.05)
    assert (with_negatives - positives).item() == pytest.approx((4 / 3) ** 2, rel=0.05)


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


def test_goal_draws_with_their_own_generator_leave_the_agents_generator_alone():
    """The probes draw goals as training does, from a generator they pass, not the agent's."""
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), imagination_alpha=0.5)
    model.learn(30)
    state = model._rng.bit_generator.state
    goals, kinds = model.sample_imagination_goals(200, rng=np.random.default_rng(3))
    again, kinds_again = model.sample_imagination_goals(200, rng=np.random.default_rng(3))
    task = model.task_goal_samples("evaluation", 4, np.random.default_rng(3))
    assert model._rng.bit_generator.state == state
    np.testing.assert_array_equal(goals, again)
    np.testing.assert_array_equal(kinds, kinds_again)
    assert set(np.unique(kinds)) == {0, 1, 2} and task.shape == (4, 1)
    model.sample_imagination_goals(10)  # without one: the agent's own, as in training
    assert model._rng.bit_generator.state != state


def test_replayed_imagination_goals_come_from_the_batch_or_the_buffer():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), imagination_alpha=0.0)
    model.learn(30)
    stored = model.replay_buffer.states[0, : model.replay_buffer.pos[0], -1]
    batch = np.array([[100.0], [200.0], [300.0]], dtype=np.float32)  # not in the buffer
    goals, kinds = model.sample_imagination_goals(600, batch)
    assert (kinds == 2).all() and set(goals[:, 0]) == {100.0, 200.0, 300.0}  # PEG: the batch's goals, each drawn
    model.replay_goals = "buffer"
    goals, _ = model.sample_imagination_goals(600, batch)
    assert np.isin(goals[:, 0], stored).all()
    with pytest.raises(ValueError, match="replay_goals"):
        tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), replay_goals="future")


def test_own_goal_fraction_replaces_that_share_of_the_replayed_goals_by_the_starts_own():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), imagination_alpha=0.2)
    model.own_goal_fraction = 0.25
    model.learn(30)
    n = 20_000
    batch = np.full((8, 1), 100.0, dtype=np.float32)
    own = np.arange(n, dtype=np.float32)[:, None] + 1000.0
    goals, kinds = model.sample_imagination_goals(n, batch, own)
    for kind, p in ((2, 0.8 * 0.75), (3, 0.8 * 0.25)):
        share = np.mean(kinds == kind)
        assert abs(share - p) < 4 * np.sqrt(p * (1 - p) / n), (kind, share)
    np.testing.assert_array_equal(goals[kinds == 3], own[kinds == 3])  # each start's own goal, in its row
    assert (goals[kinds == 2] == 100.0).all()
    with pytest.raises(ValueError, match="own_goals"):
        model.sample_imagination_goals(10, batch)
    with pytest.raises(ValueError, match="own_goal_fraction"):
        tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), own_goal_fraction=1.5)


def test_training_gives_each_start_the_achieved_goal_of_its_own_replayed_state():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), own_goal_fraction=1.0)
    sampled, calls = [], []
    sample, draw = model.replay_buffer.sample, model.sample_imagination_goals

    def record_batch(*args, **kwargs):
        sampled.append(sample(*args, **kwargs))
        return sampled[-1]

    def record_goals(n, batch_goals=None, own_goals=None):
        calls.append((batch_goals, own_goals))
        return draw(n, batch_goals, own_goals)

    model.replay_buffer.sample, model.sample_imagination_goals = record_batch, record_goals
    model.learn(model.learning_starts + 4)
    assert calls
    states = sampled[-1][0]  # (L, B, state_dim), time-major like the flat starts
    batch_goals, own_goals = calls[-1]
    np.testing.assert_array_equal(batch_goals, states.reshape(-1, states.shape[-1])[:, -1:])
    assert len(own_goals) == (model.imagination_starts or len(batch_goals))
    assert np.isin(own_goals[:, 0], batch_goals[:, 0]).all()


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


def test_replay_buffer_save_load_round_trip_and_an_interrupted_save_keeps_the_previous_file(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
):
    import pickle

    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0))
    model.learn(80)
    model.save_replay_buffer(tmp_path / "buffer.pkl")
    before = (tmp_path / "buffer.pkl").read_bytes()
    size = model.replay_buffer.size()
    model.learn(40, reset_num_timesteps=False)

    def killed(*args: Any, **kwargs: Any) -> None:
        raise KeyboardInterrupt  # as a kill while the pickle is written

    monkeypatch.setattr(pickle, "dump", killed)
    with pytest.raises(KeyboardInterrupt):
        model.save_replay_buffer(tmp_path / "buffer.pkl")
    assert (tmp_path / "buffer.pkl").read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["buffer.pkl"]  # no temporary file left behind
    monkeypatch.undo()
    model.load_replay_buffer(tmp_path / "buffer.pkl")
    assert model.replay_buffer.size() == size


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
    with pytest.raises(ValueError, match="distance_warmup"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", distance_warmup=-1)
    with pytest.raises(ValueError, match="distance_on_replay must be True or False"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", distance_on_replay="yes")
    with pytest.raises(ValueError, match="peg_elite_fraction"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", peg_elite_fraction=0.0)
    with pytest.raises(ValueError, match="compile_train_step must be True or False"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", compile_train_step="yes")
    bad = [
        ({"learning_rate": 0.0}, r"learning_rate must be > 0.0, got 0.0"),
        ({"expl_reward_scale": float("nan")}, r"expl_reward_scale must be a finite number"),
        ({"batch_length": 2.5}, r"batch_length must be an integer"),
        ({"gamma": "0.9"}, r"gamma must be a number in \[0, 1\], got '0.9'"),
        ({"imagination_alpha": 1.5}, r"imagination_alpha must be a number in \[0, 1\]"),
        # 40 rows per env hold no 50-step sequence: nothing would ever be trained
        ({"buffer_size": 40, "batch_length": 50}, r"buffer_size=40 keeps 40 steps per env .* at least 50"),
    ]
    for kwargs, message in bad:
        with pytest.raises((TypeError, ValueError), match=message):
            MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", **kwargs)
    for kwargs, message in [
        ({"kl_balance": 5.0}, r"kl_balance must be a number in \[0, 1\]"),
        ({"free_nats": -1.0}, r"free_nats must be >= 0.0"),
    ]:
        with pytest.raises(ValueError, match=message):
            tiny("GCRL/GrowingTreeGoal-v0", policy_kwargs={**TINY, **kwargs})
    with pytest.raises(ValueError, match="n_threads"):
        MoReFree("MultiInputPolicy", "GCRL/GrowingTreeGoal-v0", n_threads=0)
    with pytest.raises(ValueError, match="head_hidden"):
        tiny("GCRL/GrowingTreeGoal-v0", policy_kwargs={**TINY, "head_hidden": 0})
    with pytest.raises(ValueError, match="ensemble_size"):
        tiny("GCRL/GrowingTreeGoal-v0", policy_kwargs={**TINY, "ensemble_size": 1})
    with pytest.raises(ValueError, match="actor_lr"):
        tiny("GCRL/GrowingTreeGoal-v0", policy_kwargs={**TINY, "actor_lr": 0.0})
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
    explorer = ExplorerCheck()
    model.learn(400, callback=[ResetFreeCallback(), explorer])
    wrapper = env.envs[0]
    go_explore = wrapper.get_wrapper_attr("agent_goal_scheduler"), wrapper.get_wrapper_attr("agent_explores")
    peg = go_explore[0]
    assert isinstance(peg, PEGScheduler) and go_explore[1]
    assert wrapper.get_wrapper_attr("interventions") == 1  # one physical reset in 400 steps
    assert peg.n_planned > 0 and peg.n_fallback > 0  # novelty until learning starts, PEG after
    assert explorer.explorer_steps > 0  # Explore phases executed pi_E's actions
    counts = wrapper.get_wrapper_attr("goal_counts")
    assert counts.get("explore", 0) > 0
    # one continuous stream: only the first row is a start
    buffer = model.replay_buffer
    assert buffer.is_first[0, : buffer.pos[0]].sum() == 1
    assert not peg.planning  # detached after learn (not pickled with the env)
    # evaluation stays episodic: an eval env with the same wrapper, never switched
    eval_env = Monitor(make(gym.make("GCRL/GrowingTreeGoal-v0")))
    _, lengths = evaluate_policy(model, eval_env, n_eval_episodes=2, return_episode_rewards=True)
    assert lengths == [40, 40]


def test_go_phases_run_their_full_length_after_the_goal_is_reached():
    """Algorithm 1: pi_G acts for all H_G steps of a Go phase, also once the commanded goal is reached; the wrapper's
    early end at the env's success is the ablation ``end_go_on_success=True``."""

    def go_steps_after_success(env: GoExploreWrapper) -> tuple[int, int]:
        env.set_training_mode(True)
        obs, _ = env.reset(seed=0)
        goal = obs["desired_goal"][0]
        reached, go_after = None, 0
        for t in range(env.go_steps):
            if env.acting_policy != "goal":
                break
            height = obs["achieved_goal"][0]
            obs, _, _, _, info = env.step(np.clip([(goal - height) / 0.1], -1, 1))
            if reached is None and info["is_success"]:
                reached = t
            elif reached is not None:
                go_after += 1
        assert reached is not None, "the goal was not reached"
        return reached, go_after

    make = lambda **kw: morefree_go_explore(  # noqa: E731
        ResetFreeWrapper(gym.make("GCRL/GrowingTreeGoal-v0"), eval_horizon=60), alpha=1.0, **kw
    )
    reached, go_after = go_steps_after_success(make())
    assert reached < 15 and reached + 1 + go_after == 30  # H_G = 30 steps of pi_G, however early it arrives
    assert go_steps_after_success(make(end_go_on_success=True))[1] == 0


def test_goal_requests_are_answered_through_the_wrapper_and_an_open_one_stops_the_step():
    env = reset_free_env(eval_horizon=20)(gym.make("GCRL/GrowingTreeGoal-v0"))
    env.set_training_mode(True)
    env.reset(seed=0)
    assert env.takes_planned_goals and env.goal_request() is None
    env.set_goal_planning(True)
    info: dict[str, Any] = {}
    while not info.get(GOAL_REQUEST_KEY):  # forward/back pairs (alpha) are not planned
        _, info = env.reset()
    with pytest.raises(RuntimeError, match="answer_goal_request"):
        env.step(env.action_space.sample())
    request, rng = env.goal_request()
    assert rng is env.get_wrapper_attr("_rng")  # the planner draws from the wrapper's generator
    obs = env.answer_goal_request(np.array([1.5]), rng)
    assert obs["desired_goal"].tolist() == [1.5] and env.goal.tolist() == [1.5]
    assert obs["achieved_goal"].tolist() == request["achieved_goal"].tolist()
    assert env.step(env.action_space.sample())[0]["desired_goal"].tolist() == [1.5]
    assert env.planned_goal_counts["planned"] == 1
    with pytest.raises(RuntimeError, match="no goal request"):
        env.answer_goal_request(None, rng)
    env.set_goal_planning(False)  # the fallback's goals again, no request
    assert not any(env.reset()[1].get(GOAL_REQUEST_KEY) for _ in range(20))
    plain = GoExploreWrapper(ResetFreeWrapper(gym.make("GCRL/GrowingTreeGoal-v0"), eval_horizon=20))
    assert not plain.takes_planned_goals and plain.acting_policy == "goal"
    with pytest.raises(ValueError, match="takes_planned_goals"):
        plain.set_goal_planning(True)


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
    "GCRL/PointUMazeGoal-v0": 2,
    "GCRL/SawyerDoor-v0": 5,
    "GCRL/Tabletop-v0": 1,
    "GCRL/ErgodicFetchPush-v0": 2,
    "GCRL/ErgodicFetchPickAndPlace-v0": 2,
    "GCRL/FetchPushHard-v0": 2,
    "GCRL/FetchPickAndPlaceHard-v0": 2,
    "GCRL/AntArena-v0": 2,
}
#: exploration alpha (env) and imagination alpha of each method: MoReFree (the env's default section) and its variants
METHOD_ALPHAS = {
    "morefree": (0.2, 0.2),
    "peg": (0.0, 0.0),
    "wo_bf": (0.0, 0.2),
    "wo_imag": (0.2, 0.0),
    "own_goal": (0.2, 0.2),
}


def test_zoo_configs_cover_every_task_method_and_preset():
    from sb3_gcrl.zoo_config import read_zoo_config, split_section_key

    root = Path(__file__).resolve().parents[1] / "zoo_configs"
    seen = set()
    for preset, file in (("cpu", "morefree.yml"), ("thesis", "morefree_thesis.yml")):
        for key, hyperparams in read_zoo_config(root / file).items():
            task, variant = split_section_key(key)
            method = variant or "morefree"
            seen.add((task, method, preset))
            where = f"{file} ({key})"
            assert hyperparams["train_ratio"] == TRAIN_RATIO[task], where
            assert any("ResetFreeCallback" in str(c) for c in hyperparams["callback"]), where
            (go_explore,) = (w for w in hyperparams["env_wrapper"] if "sb3_gcrl.morefree.morefree_go_explore" in w)
            env_alpha, imagination_alpha = METHOD_ALPHAS[method]
            assert go_explore["sb3_gcrl.morefree.morefree_go_explore"]["alpha"] == env_alpha, where
            assert hyperparams.get("imagination_alpha", env_alpha) == imagination_alpha, where
            assert hyperparams.get("own_goal_fraction", 0.0) == (0.3 if method == "own_goal" else 0.0), where
    cpu_tasks = ("GCRL/PointUMazeGoal-v0", "GCRL/Tabletop-v0")  # the CPU presets measured (docs/results.md)
    for task in TRAIN_RATIO:
        assert {(task, "morefree", "thesis"), (task, "peg", "thesis")} <= seen, task
        assert ({(task, "morefree", "cpu"), (task, "peg", "cpu")} <= seen) == (task in cpu_tasks), task
    for task in (
        "GCRL/PointUMazeGoal-v0",
        "GCRL/FetchPushHard-v0",
        "GCRL/FetchPickAndPlaceHard-v0",
        "GCRL/AntArena-v0",
    ):
        assert {(task, m, "thesis") for m in METHOD_ALPHAS if m != "own_goal"} <= seen, task  # the thesis's ablations
    assert {("GCRL/PointUMazeGoal-v0", m, preset) for m in METHOD_ALPHAS for preset in ("cpu", "thesis")} <= seen
    assert {task for task, method, _ in seen if method == "own_goal"} == {"GCRL/PointUMazeGoal-v0"}


@pytest.mark.parametrize("method", sorted(METHOD_ALPHAS))
def test_pointumaze_cpu_configs_train_with_the_alphas_they_state(method: str):
    from rl_zoo3.utils import get_wrapper_class

    from sb3_gcrl.zoo_config import resolve_config

    env_id = "GCRL/PointUMazeGoal-v0"  # the CPU preset (morefree.yml): the default section, or a variant
    hyperparams = resolve_config("morefree", env_id, None if method == "morefree" else method).hyperparams
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
def test_vec_wrappers_are_seen_through():
    """PEG goals and pi_E's Explore actions through a VecEnv wrapper (subprocess envs: tests/test_subproc.py)."""
    from stable_baselines3.common.vec_env import VecMonitor

    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0, wrapper_class=reset_free_env(eval_horizon=20))
    model = tiny(VecMonitor(env))
    explorer = ExplorerCheck()
    model.learn(200, callback=[ResetFreeCallback(), explorer])
    assert env.get_attr("planned_goal_counts")[0]["planned"] > 0 and explorer.explorer_steps > 0
    # the reset infos are read under the VecEnv wrapper: one stream, restarted only at the physical start
    assert model.replay_buffer.is_first[0, : model.replay_buffer.pos[0]].sum() == 1


# ------------------------------------------------------------------------------------------------- PEG planner
def test_peg_planner_converges_on_the_goal_the_explorer_values_most(monkeypatch: pytest.MonkeyPatch):
    env = make_vec_env("GCRL/PointUMazeGoal-v0", n_envs=1, seed=0)
    model = tiny(env, learning_starts=10, peg_samples=200, peg_iterations=5)
    model.learn(20)
    best = np.array([1.0, 1.0])
    scored = []

    def fitness(policy: Any, start: LatentState, candidates: np.ndarray, horizon: int, *settings: float) -> th.Tensor:
        assert (candidates >= -2.5).all() and (candidates <= 2.5).all()  # clipped to the desired_goal box
        scored.append(len(candidates))
        return -th.as_tensor(np.linalg.norm(candidates - best, axis=-1))

    monkeypatch.setattr(peg, "peg_fitness", fitness)
    obs = {k: v[0] for k, v in env.reset().items()}
    goals = np.array([model.plan_exploratory_goal(obs, np.random.default_rng(s)) for s in range(5)])
    assert scored == [200] * 25  # 5 plans x 5 iterations of 200 candidates
    assert np.linalg.norm(goals - best, axis=-1).max() < 0.1, goals
    untrained = tiny(env, learning_starts=1000)
    assert untrained.plan_exploratory_goal(obs, np.random.default_rng(0)) is None  # before training: the fallback


def test_peg_fitness_sums_the_explorers_lambda_returns_along_pi_gs_imagined_path():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), learning_starts=10)
    model.learn(30)
    policy = model.policy
    start = policy.hold_latent(th.zeros(1, policy.state_dim))
    candidates = np.array([[-1.0], [0.5], [1.5]])
    th.manual_seed(0)
    with th.no_grad():
        fitness = peg.peg_fitness(policy, start, candidates, 4, model.gamma, model.lambda_, model.expl_reward_scale)
    th.manual_seed(0)  # the same draws, by hand
    with th.no_grad():
        goals = symlog(th.as_tensor(candidates, dtype=th.float32))
        latent, feats, actions = start.expand(3), [], []
        feats.append(latent.feat)
        for _ in range(4):
            action = policy.actor_g.act(latent.feat, goals)[0]
            latent = policy.world_model.rssm.img_step(latent, action)
            feats.append(latent.feat)
            actions.append(action)
        feat = th.stack(feats)
        rewards = policy.ensemble.disagreement(feat[:-1], th.stack(actions))
        expected = lambda_returns(rewards, policy.critic_e_target(feat), model.gamma, model.lambda_).sum(0)
    th.testing.assert_close(fitness, expected)


# ------------------------------------------------------------------------------------------------- diagnostics
def test_diagnostics_read_ground_truth_distances_goal_sensitivity_and_critic_calibration(
    monkeypatch: pytest.MonkeyPatch,
):
    from sb3_gcrl.morefree.diagnostics import (
        MoReFreeDiagnosticsCallback,
        critic_calibration,
        distance_minimum_error,
        distance_rank_correlation,
        format_diagnostics,
        goal_sensitivity,
        parse_diagnostics,
        true_distance,
    )

    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0)
    model = tiny(env, learning_starts=30)
    callback = MoReFreeDiagnosticsCallback(diagnose_freq=50, n=32)
    model.learn(200, callback=callback)
    assert [t for t, _ in callback.history] == [50, 100, 150, 200]
    resumed = MoReFreeDiagnosticsCallback(diagnose_freq=50, n=32)  # a run continued from a checkpoint at 200 steps
    model.learn(60, callback=resumed, reset_num_timesteps=False)
    assert [t for t, _ in resumed.history] == [250]  # on the uninterrupted run's grid, not at 201 and 251
    printed = "\n".join(["eval@0: something else", *(format_diagnostics(t, f) for t, f in callback.history)])
    parsed = parse_diagnostics(printed)
    assert [t for t, _ in parsed] == [50, 100, 150, 200]
    for (_, figures), (_, read) in zip(callback.history, parsed):
        assert read.keys() == figures.keys()
        np.testing.assert_allclose(list(read.values()), list(figures.values()), atol=1e-4)
    assert set(callback.history[0][1]) >= {"distance_rank_correlation", "goal_sensitivity", "critic_calibration"}
    # (a) a distance equal to the true one (|a - g| on GrowingTree) correlates perfectly; its negative at -1
    base = env.envs[0].unwrapped
    np.testing.assert_allclose(true_distance(base, np.array([[0.0], [1.0]]), np.array([0.5])), [0.5, 0.5])
    exact = lambda a, g: (symexp(a) - symexp(g)).abs().sum(-1)  # noqa: E731  (D reads symlog goals)
    monkeypatch.setattr(model.policy.distance, "forward", exact)
    assert distance_rank_correlation(model, base, 64) == pytest.approx(1.0)
    assert distance_minimum_error(model, base, 256) == 0.0  # its minimum is at the replayed state nearest the goal
    # a distance whose minimum sits halfway between 0 and the goal: by hand, with the function's own draws
    monkeypatch.setattr(model.policy.distance, "forward", lambda a, g: (symexp(a) - 0.5 * symexp(g)).abs().sum(-1))
    rng = np.random.default_rng(3)
    states, goals = (model.replay_buffer.sample_states(k, rng)[:, -1] for k in (256, 8))
    by_hand = [abs(states[np.argmin(abs(states - 0.5 * g))] - g) - abs(states - g).min() for g in goals]
    error = distance_minimum_error(model, base, 256, seed=3, goals="replay")
    assert error == pytest.approx(np.mean(by_hand), abs=1e-5) and error > 0.05
    monkeypatch.setattr(model.policy.distance, "forward", lambda a, g: -exact(a, g))
    assert distance_rank_correlation(model, base, 64) == pytest.approx(-1.0)
    # (b) an actor that ignores its goal has no goal sensitivity; one that copies the goal has |g_a - g_b| / 2
    model.policy.actor_g.act = lambda feat, goal, deterministic=False: (th.tanh(feat[:, :1]), th.zeros(len(feat)))
    assert goal_sensitivity(model, 64) == 0.0
    model.policy.actor_g.act = lambda feat, goal, deterministic=False: (goal, th.zeros(len(feat)))
    assert 0.05 < goal_sensitivity(model, 64) <= 1.0

    # (c) imagined paths that end at 3 x their start, rewards 0, gamma = lambda = 1 and V = 2 x feature 0: the
    # returns are 6 x feature 0 of the starts and V 2 x of it, a calibration of 1/3; a constant critic gives 0
    def imagine(start: LatentState, goals: th.Tensor) -> tuple[th.Tensor, th.Tensor, th.Tensor]:
        feat = th.cat([start.feat, start.feat])
        feats = th.stack([feat, 2 * feat, 3 * feat])
        return feats, th.zeros(2, len(feat), 1), th.zeros(2, len(feat))

    monkeypatch.setattr(model, "imagine", imagine)
    monkeypatch.setattr(model, "goal_rewards", lambda achieved, goals: th.zeros(achieved.shape[0] - 1, len(goals)))
    monkeypatch.setattr(model.policy.critic_g, "forward", lambda feat, goal: 2 * feat[..., 0])
    monkeypatch.setattr(model.policy.critic_g_target, "forward", lambda feat, goal: 2 * feat[..., 0])
    model.gamma, model.lambda_ = 1.0, 1.0
    assert critic_calibration(model, 64) == pytest.approx(1 / 3, rel=1e-5)
    monkeypatch.setattr(model.policy.critic_g, "forward", lambda feat, goal: th.zeros(feat.shape[:-1]))
    assert critic_calibration(model, 64) == 0.0


def test_goal_holding_compares_pi_g_with_staying_at_the_goal_by_hand(monkeypatch: pytest.MonkeyPatch):
    """Known pieces on GrowingTree: the latent's first unit is the height, each imagined step adds 0.1 x the action,
    D is the true distance and V_G = -10 x it; replayed heights -1, -0.99, ..., 1; the evaluation goal 0.5."""
    from sb3_gcrl.morefree.diagnostics import HOLD_FIGURES, goal_holding

    env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0)
    model = tiny(env)
    base = env.envs[0].unwrapped
    heights = np.round(np.linspace(-1.0, 1.0, 201), 2)
    for i, h in enumerate(heights):
        model.replay_buffer.add(0, np.array([h, h], dtype=np.float32), None if i == 0 else np.zeros(1, np.float32))
    policy = model.policy
    deter_dim, stoch_dim = policy.net_kwargs["deter"], policy.net_kwargs["stoch"]

    def latent_at(height: th.Tensor) -> LatentState:
        deter = th.zeros(len(height), deter_dim)
        deter[:, 0] = height
        zeros = th.zeros(len(height), stoch_dim)
        return LatentState(deter, zeros, zeros, zeros + 1.0)

    def img_step(latent: LatentState, action: th.Tensor, mode: bool = False) -> LatentState:
        return latent_at(latent.deter[:, 0] + 0.1 * action[:, 0])

    exact = lambda a, g: (symexp(a) - symexp(g)).abs().sum(-1)  # noqa: E731  (D reads symlog goals)
    monkeypatch.setattr(model, "task_goal_samples", lambda kind, n, rng=None: np.full((n, 1), 0.5, dtype=np.float32))
    monkeypatch.setattr(policy, "hold_latent", lambda states, deterministic=False: latent_at(states[:, -1]))
    monkeypatch.setattr(policy.world_model.rssm, "img_step", img_step)
    monkeypatch.setattr(policy.world_model, "decode_goal", lambda feat: symlog(feat[..., :1]))
    monkeypatch.setattr(policy.distance, "forward", exact)
    critic = lambda feat, goal: -10 * (feat[..., 0] - symexp(goal)[..., 0]).abs()  # noqa: E731
    monkeypatch.setattr(policy.critic_g, "forward", critic)
    monkeypatch.setattr(policy.critic_g_target, "forward", critic)
    model.gamma, model.lambda_ = 0.9, 1.0  # lambda = 1: the lambda-return is the rewards plus the bootstrap

    def by_hand(push: float) -> dict[str, float]:
        rng = np.random.default_rng(4)
        gaps, stays, ends, at, beside = [], [], [], [], []
        objective: dict[str, list[np.ndarray]] = {"objective": [], "reward": [], "bootstrap": []}
        discounts = 0.9 ** np.arange(6)
        for _ in range(2):
            states = model.replay_buffer.sample_states(300, rng)[:, -1].astype(np.float64)
            truth = np.abs(states - 0.5)
            starts = states[np.argsort(truth, kind="stable")[:3]]
            path = starts[None] + 0.1 * push * np.arange(1, 7)[:, None]  # (steps, starts)
            returns = discounts @ -np.abs(path - 0.5)
            gaps.append((returns - discounts.sum() * -np.abs(starts - 0.5)) / discounts.sum())
            # the training objective over imagination_horizon steps: pi_G against the zero action (which stays here)
            h = model.imagination_horizon
            short = starts[None] + 0.1 * push * np.arange(1, h + 1)[:, None]
            reward_gap = 0.9 ** np.arange(h) @ (np.abs(starts - 0.5)[None] - np.abs(short - 0.5))
            bootstrap_gap = 0.9**h * -10 * (np.abs(short[-1] - 0.5) - np.abs(starts - 0.5))
            objective["reward"].append(reward_gap)
            objective["bootstrap"].append(bootstrap_gap)
            objective["objective"].append(reward_gap + bootstrap_gap)
            stays.append((np.abs(path - 0.5) <= 0.25).ravel())
            ends.append(np.abs(path[-1] - 0.5))
            at.append(truth[truth <= 0.125])
            beside.append(truth[(truth >= 0.25) & (truth <= 0.5)])
        flat = lambda parts: float(np.concatenate(parts).mean())  # noqa: E731
        return {
            "hold_objective_gap": flat(objective["objective"]),
            "hold_reward_gap": flat(objective["reward"]),
            "hold_bootstrap_gap": flat(objective["bootstrap"]),
            "hold_return_gap": flat(gaps),
            "hold_stay_share": flat(stays),
            "hold_leave_distance": flat(ends),
            "distance_at_goal": flat(at),
            "distance_beside_goal": flat(beside),
            "value_at_goal": -10 * flat(at),
            "value_beside_goal": -10 * flat(beside),
        }

    for push in (0.0, 1.0, -0.45):
        monkeypatch.setattr(
            policy.actor_g,
            "act",
            lambda feat, goal, deterministic=False, push=push: (th.full((len(feat), 1), push), None),
        )
        figures = goal_holding(model, base, 0.25, n_goals=2, n_states=300, starts_per_goal=3, horizon=6, seed=4)
        assert list(figures) == list(HOLD_FIGURES)
        expected = by_hand(push)
        for name in HOLD_FIGURES:
            assert figures[name] == pytest.approx(expected[name], abs=1e-5), (push, name)
    # a pi_G that stays loses nothing against staying; one that drives off loses, and leaves the goal zone
    assert by_hand(0.0)["hold_return_gap"] == pytest.approx(0.0, abs=1e-7) and by_hand(0.0)["hold_stay_share"] == 1.0
    assert by_hand(1.0)["hold_return_gap"] < -0.1 and by_hand(1.0)["hold_stay_share"] < 0.5
    assert by_hand(1.0)["hold_objective_gap"] < 0 and by_hand(0.0)["hold_objective_gap"] == 0.0


def growing_tree_episodes(goals: tuple[float, ...], steps: int = 12) -> list[gym.Env]:
    return [gym.make("GCRL/GrowingTreeGoal-v0", goal=g, terminate_at_goal=True, max_episode_steps=steps) for g in goals]


def test_evaluation_rollouts_act_as_evaluate_policy_and_match_a_hand_computation(monkeypatch: pytest.MonkeyPatch):
    from sb3_gcrl.morefree.diagnostics import ROLLOUT_FIGURES, evaluation_rollouts

    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), learning_starts=30)
    model.learn(120)
    goals = (0.3, 0.75, -1.0)
    # (a) the real episodes are those of predict with episode_start (what evaluate_policy runs), trained nets
    figures = evaluation_rollouts(model, growing_tree_episodes(goals), seed=5)
    assert list(figures) == list(ROLLOUT_FIGURES)
    successes, finals = [], []
    for i, env in enumerate(growing_tree_episodes(goals)):
        obs, _ = env.reset(seed=5 + i)
        start, done = True, False
        while not done:
            action, _ = model.predict(obs, episode_start=np.array([start]), deterministic=True)
            obs, _, terminated, truncated, info = env.step(action)
            start, done = False, terminated or truncated
        successes.append(info["is_success"])
        finals.append(abs(obs["achieved_goal"][0] - obs["desired_goal"][0]))
    assert figures["rollout_success"] == pytest.approx(np.mean(successes))
    assert figures["rollout_final_distance"] == pytest.approx(np.mean(finals), abs=1e-6)
    assert np.isnan(figures["rollout_imagined_success"])  # GrowingTree's task states no success radius
    # (b) known pieces: pi_G always grows by the full 0.1, the decoder always says 0.5, D is the true distance.
    # From height 0 the episodes toward 0.3 / 0.75 / -1.0 end at 3 / 7 / 12 steps (success within 0.1; the last by
    # the time limit).
    monkeypatch.setattr(
        model.policy.actor_g,
        "act",
        lambda feat, goal, deterministic=False: (th.ones(len(feat), 1), th.zeros(len(feat))),
    )
    monkeypatch.setattr(
        model.policy.world_model, "decode_goal", lambda feat: symlog(th.full((*feat.shape[:-1], 1), 0.5))
    )
    monkeypatch.setattr(model.policy.distance, "forward", lambda a, g: (symexp(a) - symexp(g)).abs().sum(-1))
    model.imagination_horizon = 4
    figures = evaluation_rollouts(model, growing_tree_episodes(goals), success_threshold=0.3)
    lengths = (3, 7, 12)
    paths = [0.1 * np.arange(n + 1) for n in lengths]
    assert figures["rollout_success"] == pytest.approx(2 / 3)
    assert figures["rollout_final_distance"] == pytest.approx(np.mean([0.0, 0.05, 2.2]), abs=1e-5)
    # imagined: every episode ends at the decoded 0.5, within 0.3 of the goals 0.3 and 0.75 only
    assert figures["rollout_imagined_success"] == pytest.approx(2 / 3)
    assert figures["rollout_optimism"] == 0.0
    assert figures["rollout_imagined_final_distance"] == pytest.approx(np.mean([0.2, 0.25, 1.5]), abs=1e-5)
    reconstruction = np.concatenate([np.abs(0.5 - path[:-1]) for path in paths])
    assert figures["rollout_reconstruction_error"] == pytest.approx(reconstruction.mean(), abs=1e-5)
    ahead = np.concatenate([np.abs(0.5 - path[4:]) for path in paths])  # states 4 steps after a posterior
    assert figures["rollout_model_error"] == pytest.approx(ahead.mean(), abs=1e-5)
    assert figures["rollout_distance_correlation"] == pytest.approx(1.0)
    assert figures["rollout_distance_correlation_near"] == pytest.approx(1.0)  # the heights within 0.6 of a goal
    assert figures["rollout_imagined_outside"] == 0.0  # GrowingTree's distance is defined everywhere
    assert figures["rollout_reached"] == pytest.approx(2 / 3) and figures["rollout_held"] == 1.0  # they stop there
    # episodes that do not stop at the goal: toward 0.75 (within 0.3 at heights 0.5-1.0 of 0.1-1.2), never toward -1
    passing = [gym.make("GCRL/GrowingTreeGoal-v0", goal=g, max_episode_steps=12) for g in (0.75, -1.0)]
    figures = evaluation_rollouts(model, passing, success_threshold=0.3)
    assert figures["rollout_success"] == 0.0 and figures["rollout_reached"] == 0.5
    assert figures["rollout_held"] == pytest.approx(6 / 8)  # heights 0.5 ... 1.2 after the first arrival
    # a distance that is right far away and flat within 0.6 of the goal (ranks by true distance beyond, ties near)
    flat_near = lambda a, g: (symexp(a) - symexp(g)).abs().sum(-1).clamp(min=0.6)  # noqa: E731
    monkeypatch.setattr(model.policy.distance, "forward", flat_near)
    figures = evaluation_rollouts(model, passing, success_threshold=0.3)
    assert figures["rollout_distance_correlation"] > 0.5 and np.isnan(figures["rollout_distance_correlation_near"])
    assert np.isnan(evaluation_rollouts(model, passing)["rollout_distance_correlation_near"])  # no success radius
    # a model that puts every episode at the goal toward 1.5 is optimistic where the env disagrees
    figures = evaluation_rollouts(model, growing_tree_episodes((1.5, 0.5)), success_threshold=0.3)
    assert figures["rollout_success"] == pytest.approx(0.5)  # 1.5 is out of reach in 12 steps of 0.1
    assert figures["rollout_imagined_success"] == pytest.approx(0.5)
    assert figures["rollout_optimism"] == 0.0
    monkeypatch.setattr(
        model.policy.world_model, "decode_goal", lambda feat: symlog(th.full((*feat.shape[:-1], 1), 1.5))
    )
    figures = evaluation_rollouts(model, growing_tree_episodes((1.5, 0.5)), success_threshold=0.3)
    assert figures["rollout_imagined_success"] == pytest.approx(0.5) and figures["rollout_optimism"] == pytest.approx(
        0.5
    )
    with pytest.raises(ValueError, match="at least one env"):
        evaluation_rollouts(model, [])


def test_evaluation_rollouts_count_imagined_ends_inside_a_maze_wall(monkeypatch: pytest.MonkeyPatch):
    from sb3_gcrl.morefree.diagnostics import evaluation_rollouts

    model = tiny(make_vec_env("GCRL/PointUMazeGoal-v0", n_envs=1, seed=0))
    envs = [gym.make("GCRL/PointUMazeGoal-v0", max_episode_steps=5) for _ in range(2)]
    world_model = model.policy.world_model
    for point, outside in (((0.0, 0.0), 1.0), ((-1.0, 1.0), 0.0)):  # the U's inner wall; the goal's cell
        decoded = symlog(th.tensor(point))
        monkeypatch.setattr(world_model, "decode_goal", lambda feat, d=decoded: d.expand(*feat.shape[:-1], 2))
        figures = evaluation_rollouts(model, envs)
        assert figures["rollout_imagined_outside"] == outside
        assert np.isnan(figures["rollout_imagined_final_distance"]) == bool(outside)
        assert figures["rollout_imagined_success"] == 1.0 - outside  # within PointUMaze's 0.45 of (-1, 1)


def test_the_probes_leave_training_as_it_would_have_been_without_them():
    from sb3_gcrl.morefree.diagnostics import MoReFreeDiagnosticsCallback

    params = []
    for callback in (None, MoReFreeDiagnosticsCallback(diagnose_freq=40, n=16, rollout_episodes=2)):
        model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), learning_starts=30)
        model.learn(160, callback=callback)
        params.append(th.nn.utils.parameters_to_vector(model.policy.parameters()).detach())
    assert len(callback.history) == 3  # probes at 80, 120, 160 (none before the first update)
    th.testing.assert_close(params[0], params[1], rtol=0, atol=0)


def test_diagnostics_callback_runs_the_evaluation_episodes_of_the_training_env_or_names_the_fix():
    from sb3_gcrl.morefree.diagnostics import ROLLOUT_FIGURES, MoReFreeDiagnosticsCallback

    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), learning_starts=30)
    callback = MoReFreeDiagnosticsCallback(diagnose_freq=50, n=16, rollout_episodes=2)
    model.learn(60, callback=callback)
    assert set(ROLLOUT_FIGURES) <= set(callback.history[-1][1])
    own = make_vec_env(lambda: gym.wrappers.TimeLimit(GrowingTreeGoalEnv(), 50), n_envs=1, seed=0)
    with pytest.raises(ValueError, match="rollout_env"):
        tiny(own, learning_starts=5).learn(10, callback=MoReFreeDiagnosticsCallback(diagnose_freq=50, n=16))
    callback = MoReFreeDiagnosticsCallback(diagnose_freq=50, n=16, rollout_env=lambda: gym.make("GCRL/GrowingTree-v0"))
    with pytest.raises(ValueError, match="observation space"):
        tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), learning_starts=5).learn(10, callback=callback)
    tiny(own, learning_starts=30).learn(
        60, callback=MoReFreeDiagnosticsCallback(50, 16, rollout_env="GCRL/GrowingTreeGoal-v0")
    )
    with pytest.raises(TypeError, match="rollout_env"):
        MoReFreeDiagnosticsCallback(rollout_env=3)  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="rollout_episodes"):
        MoReFreeDiagnosticsCallback(rollout_episodes=-1)


@pytest.mark.slow  # compiling the three loss functions takes a few minutes on a CPU
def test_compiled_train_step_matches_the_eager_one():
    """``compile_train_step`` changes the speed of a training step, not its result: the compiled step draws its
    random numbers from PyTorch's generator, as the plain one does."""
    params, updates = [], []
    for compiled in (False, True):
        env = make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0)
        model = tiny(env, learning_starts=30, compile_train_step=compiled)
        model.learn(60)
        params.append(th.nn.utils.parameters_to_vector(model.policy.parameters()).detach())
        updates.append(model._n_updates)
    assert updates[0] == updates[1] >= 3
    th.testing.assert_close(params[0], params[1], rtol=1e-4, atol=1e-5)


def test_mixed_precision_trains_the_agent_in_bfloat16_with_float32_distributions():
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), mixed_precision=True)
    before = th.nn.utils.parameters_to_vector(model.policy.parameters()).detach().clone()
    with th.autocast("cpu", dtype=th.bfloat16):
        dist = model.policy.actor_g(th.zeros(3, model.policy.world_model.feat_dim), th.zeros(3, 1))
        assert dist.loc.dtype == th.float32 and dist.entropy().dtype == th.float32
    model.learn(200)
    after = th.nn.utils.parameters_to_vector(model.policy.parameters()).detach()
    assert model._n_updates > 10 and th.isfinite(after).all() and not th.equal(before, after)
    assert all(p.dtype == th.float32 for p in model.policy.parameters())


@pytest.mark.parametrize("native", [True, False])
def test_mixed_precision_uses_bfloat16_only_where_the_cpu_computes_it(monkeypatch: pytest.MonkeyPatch, native: bool):
    import sb3_gcrl.common.hardware as hardware

    monkeypatch.setattr(
        hardware,
        "cpu_features",
        lambda: {**dict.fromkeys(hardware.CPU_FEATURES, False), "avx2": True, "avx512_bf16": native},
    )
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), mixed_precision=True)
    dtypes = []
    original = model._autocast

    def recorded(world_model: bool = False):
        context = original(world_model)
        dtypes.append(th.get_autocast_dtype("cpu") if isinstance(context, th.autocast) else th.float32)
        return context

    model._autocast = recorded
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        model.learn(model.learning_starts + 6)
    fallbacks = [w for w in caught if "no native bfloat16" in str(w.message)]
    if native:  # AVX512-BF16: the imagination in bfloat16 (the world model's filtering stays float32 on a CPU)
        assert th.bfloat16 in dtypes and not fallbacks
    else:  # AVX2 only: float32 throughout, said once
        assert set(dtypes) == {th.float32} and len(fallbacks) == 1
        assert "AVX512-BF16" in str(fallbacks[0].message) and "mixed_precision=False" in str(fallbacks[0].message)
    assert "_bfloat16" not in model.get_parameters() and "_bfloat16" in model._excluded_save_params()


def test_learn_runs_on_n_threads_and_restores_torchs_setting():
    seen = []

    class Threads(BaseCallback):
        def _on_step(self) -> bool:
            seen.append(th.get_num_threads())
            return True

    previous = th.get_num_threads()
    th.set_num_threads(2)
    try:
        tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), n_threads=1).learn(20, callback=Threads())
        assert set(seen) == {1} and th.get_num_threads() == 2
        seen.clear()
        tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), n_threads=None).learn(20, callback=Threads())
        assert set(seen) == {2}
    finally:
        th.set_num_threads(previous)


@pytest.mark.parametrize("verbose", [0, 1])
def test_compiling_the_train_step_is_announced_once(
    monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str], verbose: int
):
    """The first compiled training step waits minutes on a CPU: one line (SB3's verbose >= 1) says so beforehand."""
    compiled: list[str] = []

    def fake_compile(function: Any, **kwargs: Any) -> Any:  # compiling itself takes minutes: not tested here
        compiled.append(function.__name__)
        return function

    monkeypatch.setattr(th, "compile", fake_compile)
    model = tiny(make_vec_env("GCRL/GrowingTreeGoal-v0", n_envs=1, seed=0), compile_train_step=True, verbose=verbose)
    model.learn(model.learning_starts + 6)
    model.learn(6, reset_num_timesteps=False)
    assert model._n_updates >= 2 and sorted(compiled) == ["_imagination_losses", "_learner_losses", "_model_losses"]
    lines = [line for line in capsys.readouterr().out.splitlines() if "torch.compile" in line]
    if verbose:
        assert len(lines) == 1
        assert "once per model in this process" in lines[0] and "minutes on a CPU" in lines[0]
        assert "compile_train_step=False skips it" in lines[0]
    else:
        assert lines == []
