"""World Models + AlphaZero (thesis 4.3, 5.4.2): the latent MDP, the heads, self-play, resume.

Self-play runs on a tiny corridor whose observations are their own latents (vision = identity)
and a small untrained deterministic memory; the real search (wmthesis.alphazero.mcts) plans.
"""
import dataclasses
import json
import pickle
from pathlib import Path

import gymnasium as gym
import h5py
import numpy as np
import pytest
import torch

from wmthesis.alphazero.config import AlphaZeroConfig
from wmthesis.alphazero.diagnosis import action_predictability, reward_error_by_depth, search_statistics
from wmthesis.alphazero.heads import AlphaZeroHeads, Evaluator, alphazero_loss, game_targets, value_targets
from wmthesis.alphazero.imitation import PolicyHeadMind, agreement, expert_games
from wmthesis.alphazero.latent_mdp import (LatentMDP, RewardModel, RewardView, State, reward_fit, reward_rows,
                                           train_reward_model)
from wmthesis.alphazero.selfplay import AlphaZeroMind, load_run, play, prior_and_q, train_alphazero
from wmthesis.alphazero.variants import VARIANTS
from wmthesis.config import for_profile
from wmthesis.core import Mind, loop
from wmthesis.envs.atari import NoopStart
from wmthesis.training import ConfigMismatch
from wmthesis.utils import read_pickle
from wmthesis.world_models.memory import Memory

pytestmark = pytest.mark.usefixtures("one_torch_thread")
L, A, H = 5, 2, 8


class Corridor(gym.Env):
    """Cells 0..4, start in 0; action 1 steps right, 0 left; reaching cell 4 pays 1 and ends
    the game. Observations are one-hot cells, float32 (5,)."""

    observation_space = gym.spaces.Box(0, 1, (L,), np.float32)
    action_space = gym.spaces.Discrete(A)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.cell, self.steps = 0, 0
        return self._observation(), {}

    def step(self, action):
        self.cell = max(0, self.cell + (1 if action == 1 else -1))
        self.steps += 1
        done = self.cell == L - 1
        return self._observation(), float(done), done, False, {}

    def _observation(self):
        return np.eye(L, dtype=np.float32)[self.cell]


def vision(frames: torch.Tensor) -> torch.Tensor:
    return frames.float()


def small_memory(seed: int = 0) -> Memory:
    torch.manual_seed(seed)
    return Memory(L, A, kind="deterministic", hidden_size=H).eval()


def tiny_config(**changes) -> AlphaZeroConfig:
    values = dict(simulations=6, games=4, train_every=2, epochs=3, batch_size=8, max_steps=10, test_every=2,
                  test_episodes=1, eval_episodes=2, lr=0.05)
    return AlphaZeroConfig(**{**values, **changes})


# ----------------------------------------------------------------------------- latent MDP
def test_latent_mdp_matches_the_memory_step_by_step():
    memory = small_memory()
    mdp = LatentMDP(memory)
    z = np.random.default_rng(0).standard_normal(L).astype(np.float32)
    state, actions = mdp.initial_state(z), [1, 0, 1]
    z_t, lstm_state = torch.from_numpy(z)[None], None
    for action in actions:
        state, reward = mdp.transition(state, action)
        with torch.no_grad():
            out = memory.step(z_t, torch.tensor([action]), lstm_state)
        np.testing.assert_allclose(state.z, out.next_latent[0].numpy(), atol=1e-5)
        np.testing.assert_allclose(state.h, out.state[0][0, 0].numpy(), atol=1e-5)
        np.testing.assert_allclose(state.c, out.state[1][0, 0].numpy(), atol=1e-5)
        assert reward == pytest.approx(float(out.reward), abs=1e-5)
        assert state.terminal == bool(out.done_logit > 0)
        z_t, lstm_state = out.next_latent, out.state
    # a batch of states steps as each one alone
    zs, hs = np.stack([z, state.z]), np.stack([np.zeros(H, np.float32), state.h])
    cs = np.stack([np.zeros(H, np.float32), state.c])
    batched = mdp.step(zs, hs, cs, np.array([0, 1]))
    alone = mdp.step(state.z, state.h, state.c, 1)
    for b, a in zip(batched, alone):
        np.testing.assert_allclose(b[1], a, atol=1e-6)


def test_done_head_decides_terminal_and_mdn_memory_is_refused():
    memory = small_memory()
    with torch.no_grad():
        memory.done.weight.zero_()
        memory.done.bias.fill_(3.0)  # sigmoid(3) > 0.5
    mdp = LatentMDP(memory)
    state, _ = mdp.transition(mdp.initial_state(np.zeros(L, np.float32)), 0)
    assert state.terminal and mdp.is_terminal(state) and mdp.action_space.n == A
    with pytest.raises(ValueError, match="deterministic"):
        LatentMDP(Memory(L, A, kind="mdn", hidden_size=H))


# ----------------------------------------------------------------------------- heads and loss
def test_evaluator_gives_softmax_priors_and_follows_training():
    heads = AlphaZeroHeads(L, H, A)
    state = State(np.arange(L, dtype=np.float32), np.ones(H, np.float32), np.zeros(H, np.float32))
    evaluator = Evaluator(heads)
    priors, value = evaluator(state)
    assert priors.sum() == pytest.approx(1.0, abs=1e-6) and value == 0.0  # the value head starts at zero
    torch.manual_seed(1)
    optimiser = torch.optim.SGD(heads.parameters(), lr=0.1)
    x = torch.randn(4, L + H)
    loss = alphazero_loss(heads, x, torch.tensor([[1.0, 0.0]] * 4), torch.ones(4), 1e-4)["loss"]
    loss.backward()
    optimiser.step()
    priors, value = evaluator(state)  # the evaluator sees the updated weights
    logits, expected_value = heads(torch.from_numpy(np.concatenate([state.z, state.h]))[None])
    assert priors.sum() == pytest.approx(1.0, abs=1e-6)
    np.testing.assert_allclose(priors, torch.softmax(logits[0], -1).detach().numpy(), atol=1e-6)
    assert value == pytest.approx(float(expected_value.detach()), abs=1e-5) and value != 0.0


def test_loss_is_value_mse_plus_policy_cross_entropy_plus_l2():
    heads = AlphaZeroHeads(1, 1, 2)
    with torch.no_grad():
        heads.policy.weight.copy_(torch.tensor([[1.0, 0.0], [0.0, 2.0]]))
        heads.policy.bias.copy_(torch.tensor([0.0, -1.0]))
        heads.value.weight.copy_(torch.tensor([[0.5, 0.5]]))
        heads.value.bias.fill_(0.0)
    x = torch.tensor([[1.0, 1.0], [2.0, 0.0]])
    pi = torch.tensor([[0.25, 0.75], [1.0, 0.0]])
    targets = torch.tensor([0.0, 3.0])
    terms = {k: float(v.detach()) for k, v in alphazero_loss(heads, x, pi, targets, l2=0.1).items()}
    # logits: [1, 1] and [2, -1]; values: 1 and 1
    log_p1, log_p2 = np.log([0.5, 0.5]), np.array([2, -1]) - np.log(np.exp(2) + np.exp(-1))
    policy = -(0.25 * log_p1[0] + 0.75 * log_p1[1] + 1.0 * log_p2[0]) / 2
    value = ((1 - 0) ** 2 + (1 - 3) ** 2) / 2
    l2 = 0.1 * (1 + 4 + 1 + 0.25 + 0.25)
    assert terms["policy"] == pytest.approx(policy, rel=1e-5)
    assert terms["value"] == pytest.approx(value, rel=1e-6)
    assert terms["l2"] == pytest.approx(l2, rel=1e-6)
    assert terms["loss"] == pytest.approx(policy + value + l2, rel=1e-5)


def test_value_targets_are_discounted_returns_and_n_step():
    rewards = [1.0, 0.0, 2.0]
    np.testing.assert_allclose(value_targets(rewards, 0.5), [1.5, 1.0, 2.0])
    np.testing.assert_allclose(value_targets(rewards, 0.5, bootstrap=4.0), [2.0, 2.0, 4.0])
    values = [10.0, 20.0, 30.0]
    np.testing.assert_allclose(value_targets(rewards, 0.5, n=1, values=values, bootstrap=40.0), [11.0, 15.0, 22.0])
    # n = 2: 1 + 0.5*0 + 0.25*30; 0 + 0.5*2 + 0.25*40; the last step has one reward left: 2 + 0.5*40
    np.testing.assert_allclose(value_targets(rewards, 0.5, n=2, values=values, bootstrap=40.0), [8.5, 11.0, 22.0])
    np.testing.assert_allclose(value_targets(rewards, 0.5, n=5, values=values), value_targets(rewards, 0.5))


# ----------------------------------------------------------------------------- the mind in the real game
def test_mind_steps_the_memory_on_the_real_actions():
    memory, config = small_memory(), tiny_config()
    mind = AlphaZeroMind(vision, LatentMDP(memory), Evaluator(AlphaZeroHeads(L, H, A)), config)
    game = play(Corridor(), mind, seed=3, index=0, train_mode=True, max_steps=10)
    T = len(game)
    assert game.features.shape == (T, L + H) and game.policies.shape == (T, A)
    np.testing.assert_allclose(game.policies.sum(1), 1.0, atol=1e-6)
    # z is the vision of each real observation; h the memory after reading the real steps before it
    env = Corridor()
    observation, _ = env.reset()
    z = [observation]
    for action in game.actions[:-1]:
        z.append(env.step(int(action))[0])
    z = torch.from_numpy(np.stack(z))
    with torch.no_grad():
        hidden = memory(z[None, :-1], torch.from_numpy(game.actions[None, :-1])).hidden[0]
    np.testing.assert_allclose(game.features[:, :L], z.numpy())
    np.testing.assert_allclose(game.features[1:, L:], hidden.numpy(), atol=1e-5)
    assert np.all(game.features[0, L:] == 0)
    # the state after the last step: the last observation and the memory after every real step
    last_observation = env.step(int(game.actions[-1]))[0]
    with torch.no_grad():
        last_hidden = memory(z[None], torch.from_numpy(game.actions[None])).hidden[0, -1]
    np.testing.assert_allclose(game.last_features[:L], last_observation)
    np.testing.assert_allclose(game.last_features[L:], last_hidden.numpy(), atol=1e-5)
    assert game.terminated == (game.rewards[-1] == 1.0) and (T == 10 or game.terminated)
    # the depth-1 reward error is the error of the rewards the mind predicted on the real steps
    errors = reward_error_by_depth(LatentMDP(memory), [game], depth=1)
    assert errors["reward_mse"][0] == pytest.approx(np.mean((game.predicted_rewards - game.rewards) ** 2), rel=1e-5)
    assert errors["zero_mse"][0] == pytest.approx(np.mean(game.rewards ** 2))
    stats = search_statistics([game], 0.99, 1.0, config.simulations)
    assert stats["root_value"].shape == stats["returns"].shape == (T,)


def test_a_greedy_game_with_decision_beta_moves_the_priors_choice_by_q_alone():
    """In a model where stepping right pays 1 and the prior leans left, the most visited action is
    right at any budget; decision_beta = 0 plays the prior's choice, left, whatever the budget; a
    large beta the higher Q, right. The visit counts (the policy targets) are recorded as before."""
    priors, q = np.array([0.6, 0.3, 0.1]), np.array([1.0, 1.2, np.nan])
    assert prior_and_q(priors, q, 1.1, 0.0).argmax() == 0 and prior_and_q(priors, q, 1.1, 10.0).argmax() == 1
    np.testing.assert_allclose(prior_and_q(priors, q, 1.1, 10.0), np.log(priors) + 10.0 * np.array([-0.1, 0.1, 0.0]))

    class RightPays(LatentMDP):
        def transition(self, state, action):
            return super().transition(state, action)[0], float(action == 1)

    mdp, evaluator = RightPays(small_memory()), lambda state: (np.array([0.6, 0.4]), 0.0)
    for simulations in (8, 40):
        actions = {}
        for beta in (None, 0.0, 50.0):
            config = tiny_config(simulations=simulations, decision_beta=beta, reuse_tree=False, normalize_q=True)
            game = play(Corridor(), AlphaZeroMind(vision, mdp, evaluator, config), seed=3, index=0, train_mode=False,
                        max_steps=3)
            actions[beta] = game.actions.tolist()
            assert (game.policies.argmax(1) == 1).all()  # the search's visits favour the paying action
        assert actions == {None: [1, 1, 1], 0.0: [0, 0, 0], 50.0: [1, 1, 1]}


def test_self_play_with_a_gumbel_root_acts_on_its_choice_and_learns_its_improved_policy():
    """Where stepping right pays 1 and the prior leans left, the Gumbel root's self-play plays the
    search's choice (no proportional warm-up), and its policy targets are the improved policy,
    which favours right; the PUCT root's are visit shares."""
    class RightPays(LatentMDP):
        def transition(self, state, action):
            return super().transition(state, action)[0], float(action == 1)

    mdp, evaluator = RightPays(small_memory()), lambda state: (np.array([0.6, 0.4]), 0.0)
    config = tiny_config(simulations=8, root="gumbel", considered=2)
    game = play(Corridor(), AlphaZeroMind(vision, mdp, evaluator, config), seed=3, index=0, train_mode=True,
                max_steps=4)
    np.testing.assert_allclose(game.policies.sum(1), 1.0, atol=1e-6)
    assert (game.policies.argmax(1) == 1).all() and (game.actions == 1).all()
    assert not np.allclose(game.policies * config.simulations, np.round(game.policies * config.simulations))


def test_noop_start_draws_its_noops_from_the_reset_seed():
    env = NoopStart(Corridor(), noop_max=30)
    counts = []
    for seed in (0, 1, 2, 0):
        env.reset(seed=seed)
        counts.append(env.unwrapped.steps)
    assert counts[0] == counts[3] and len(set(counts)) > 1 and max(counts) < 30


# ----------------------------------------------------------------------------- self-play
def test_self_play_trains_the_heads_and_keeps_the_latest_games(tmp_path):
    config = tiny_config(games=5, replay_games=3)
    run = train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path, seed=0, progress=False)
    assert run.games == 5 and [g.index for g in run.replay] == [2, 3, 4]
    assert [r["game"] for r in run.rounds] == [2, 4] and [t["game"] for t in run.tests] == [2, 4]
    assert all(1 <= t["steps"] <= config.max_steps * config.test_episodes for t in run.tests)  # the budget counts them
    for r in run.rounds:
        assert r["loss"] < r["loss_before"]
    assert [e["game"] for e in run.curve] == [1, 2, 3, 4, 5]
    assert any(p.abs().sum() > 0 for p in run.heads.parameters())


class Rollouts:
    """A stand-in for a LatentStore: ``episodes`` random Corridor walks of 30 steps (the
    latents are the one-hot cells)."""

    def __init__(self, episodes: int = 4, seed: int = 0):
        rng, env = np.random.default_rng(seed), Corridor()
        mu, actions, rewards = [], [], []
        for _ in range(episodes):
            observation, _ = env.reset()
            for _ in range(30):
                action = int(rng.integers(A))
                mu.append(observation)
                actions.append(action)
                observation, reward, done, _, _ = env.step(action)
                rewards.append(reward)
                if done:
                    observation, _ = env.reset()
        self.data = {"mu": torch.tensor(np.array(mu)), "actions": torch.tensor(actions),
                     "rewards": torch.tensor(rewards, dtype=torch.float32)}
        self.ends = np.arange(1, episodes + 1) * 30
        self.starts = self.ends - 30

    def __len__(self) -> int:
        return len(self.ends)


def test_a_run_does_not_depend_on_the_global_random_state():
    config = tiny_config(games=2, test_every=0)
    runs = []
    for other in (1, 2):
        memory = small_memory()
        torch.manual_seed(other)  # e.g. another variant trained before in the same process
        runs.append(train_alphazero(Corridor, vision, memory, config, seed=3, progress=False))
    for a, b in zip(runs[0].heads.parameters(), runs[1].heads.parameters()):
        assert torch.equal(a, b)
    assert [e["return"] for e in runs[0].curve] == [e["return"] for e in runs[1].curve]


@pytest.mark.parametrize("variant", ["monte-carlo", "n-step", "learned-reward", "imitation", "own-reward"])
def test_resumed_run_equals_an_uninterrupted_one(tmp_path, variant):
    if variant in ("learned-reward", "imitation", "own-reward"):
        config = tiny_config(**VARIANTS.changes(variant), reward_pretrain_epochs=2, reward_epochs=1,
                             eval_max_steps=8)
    else:
        config = tiny_config(value_target=variant, normalize_q=variant == "n-step")
    extra = {"rollouts": Rollouts()} if config.reward_model else {}
    if config.expert_games:
        extra["expert"] = lambda agent_seed: ZigZag()
    whole = train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path / "whole", progress=False,
                            **extra)
    train_alphazero(Corridor, vision, small_memory(), dataclasses.replace(config, games=2),
                    out_dir=tmp_path / "parts", progress=False, **extra)
    assert load_run(tmp_path / "parts").games == 2
    resumed = train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path / "parts", progress=False,
                              **extra)
    for a, b in zip(whole.heads.parameters(), resumed.heads.parameters()):
        assert torch.equal(a, b)
    assert [e["return"] for e in whole.curve] == [e["return"] for e in resumed.curve]
    assert whole.rounds == resumed.rounds and whole.tests == resumed.tests
    assert json.dumps(whole.reward_fits) == json.dumps(resumed.reward_fits)  # nan (no hit held out) == nan
    assert whole.expert == resumed.expert and bool(whole.expert) == (variant in ("imitation", "own-reward"))
    if config.reward_model:  # pretrained (and trained on the expert's games), then after each of the 2 rounds
        assert [f["game"] for f in whole.reward_fits] == ([0, 0] if config.expert_games else [0]) + [2, 4]
        assert load_run(tmp_path / "parts").config == dataclasses.asdict(config)
        for a, b in zip(whole.reward_model.state_dict().values(), resumed.reward_model.state_dict().values()):
            assert torch.equal(a, b)
    with pytest.raises(ConfigMismatch, match="lr"):
        train_alphazero(Corridor, vision, small_memory(), dataclasses.replace(config, lr=0.5),
                        out_dir=tmp_path / "parts", progress=False, **extra)
    with pytest.raises(ConfigMismatch, match="memory"):
        train_alphazero(Corridor, vision, small_memory(seed=1), config, out_dir=tmp_path / "parts", progress=False,
                        **extra)


def test_the_replay_lives_in_hdf5_and_the_checkpoint_names_its_games(tmp_path):
    config = tiny_config(games=5, replay_games=3)
    run = train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path, seed=0, progress=False)
    saved = read_pickle(tmp_path / "alphazero.pkl")
    assert saved["replay"] == {"serials": [2, 3, 4], "next_serial": 5}  # names, never the games
    with h5py.File(tmp_path / "replay.h5", "r") as f:
        assert sorted(f["games"], key=int) == ["2", "3", "4"]  # evicted games are gone from the file
    for a, b in zip(run.replay, load_run(tmp_path).replay):
        assert a.index == b.index and a.terminated == b.terminated and a.seconds == b.seconds
        for key in ("features", "policies", "actions", "rewards", "q", "last_features"):
            np.testing.assert_array_equal(getattr(a, key), getattr(b, key))


def test_games_played_after_the_last_checkpoint_are_dropped_on_resume(tmp_path):
    config = tiny_config(games=4, replay_games=10)
    train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path, progress=False)
    replay = load_run(tmp_path).replay
    replay.attach(tmp_path / "replay.h5")
    replay.append(replay.games[0])  # a game written before a crash, never named by a checkpoint
    replay.close()
    with h5py.File(tmp_path / "replay.h5", "r") as f:
        assert len(f["games"]) == 5
    assert [g.index for g in load_run(tmp_path).replay] == [0, 1, 2, 3]
    resumed = train_alphazero(Corridor, vision, small_memory(), dataclasses.replace(config, games=6),
                              out_dir=tmp_path, progress=False)
    assert [g.index for g in resumed.replay] == [0, 1, 2, 3, 4, 5]


def test_a_checkpoint_of_the_earlier_layout_is_read_and_moves_its_replay_to_hdf5(tmp_path, monkeypatch):
    """Version 1 pickled the replay's games (class ``wmthesis.agents.alphazero.Game``) inside."""
    import sys
    import types

    from wmthesis.alphazero import replay as replay_module

    config = tiny_config(games=2, test_every=0)
    run = train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path, progress=False)
    saved = read_pickle(tmp_path / "alphazero.pkl")
    saved.update(version=1, replay=list(run.replay))
    old = types.ModuleType("wmthesis.agents.alphazero")
    old.Game = replay_module.Game
    monkeypatch.setitem(sys.modules, "wmthesis.agents.alphazero", old)
    monkeypatch.setattr(replay_module.Game, "__module__", "wmthesis.agents.alphazero")
    (tmp_path / "alphazero.pkl").write_bytes(pickle.dumps(saved))
    (tmp_path / "replay.h5").unlink()
    monkeypatch.undo()
    assert b"wmthesis.agents.alphazero" in (tmp_path / "alphazero.pkl").read_bytes()
    assert [g.index for g in load_run(tmp_path).replay] == [0, 1]
    resumed = train_alphazero(Corridor, vision, small_memory(), dataclasses.replace(config, games=4),
                              out_dir=tmp_path, progress=False)
    assert [g.index for g in resumed.replay] == [0, 1, 2, 3]
    assert read_pickle(tmp_path / "alphazero.pkl")["version"] == 2
    assert [g.index for g in load_run(tmp_path).replay] == [0, 1, 2, 3]


def test_a_missing_replay_file_is_named_in_a_clear_error(tmp_path):
    train_alphazero(Corridor, vision, small_memory(), tiny_config(games=2, test_every=0), out_dir=tmp_path,
                    progress=False)
    (tmp_path / "replay.h5").unlink()
    with pytest.raises(ValueError, match="replay.h5: cannot read the self-play replay.*delete it and the checkpoint"):
        load_run(tmp_path)


def test_a_corrupt_checkpoint_is_named_in_a_clear_error(tmp_path):
    config = tiny_config(games=2, test_every=0)
    train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path, progress=False)
    checkpoint = tmp_path / "alphazero.pkl"
    checkpoint.write_bytes(checkpoint.read_bytes()[:1000])  # truncated, e.g. by a copy that stopped
    with pytest.raises(ValueError, match="alphazero.pkl is truncated or corrupt"):
        load_run(tmp_path)
    with pytest.raises(ValueError, match="truncated or corrupt"):
        train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path, progress=False)
    checkpoint.write_bytes(b"")
    with pytest.raises(ValueError, match="truncated or corrupt"):
        load_run(checkpoint)


# ----------------------------------------------------------------------------- imitation
class ZigZag(Mind):
    """An expert whose action depends on the state: right in every cell but cell `turn`, where
    it steps left (so with turn 2 it walks 0 1 2 1 2 1 ... and never reaches the goal)."""

    def __init__(self, turn: int = 2):
        self.turn = turn

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        return np.eye(A)[0 if np.argmax(state) == self.turn else 1]


def test_expert_games_record_the_experts_actions_with_the_searchs_features():
    memory = small_memory()
    games = expert_games(Corridor(), lambda agent_seed: ZigZag(), vision, LatentMDP(memory), seeds=[0, 1],
                         max_steps=9, progress=False)
    assert [len(g) for g in games] == [9, 9] and [g.index for g in games] == [0, 1]
    game = games[0]
    cells = [0, 1, 2, 1, 2, 1, 2, 1, 2]
    np.testing.assert_array_equal(game.features[:, :L], np.eye(L)[cells])
    np.testing.assert_array_equal(game.actions, [1, 1, 0, 1, 0, 1, 0, 1, 0])
    np.testing.assert_array_equal(game.policies, np.eye(A)[game.actions])
    assert game.score == 0 and not game.terminated
    with torch.no_grad():  # h is the deterministic memory after the real steps, as AlphaZeroMind records it
        hidden = memory(torch.from_numpy(game.features[None, :, :L]), torch.from_numpy(game.actions[None])).hidden[0]
    np.testing.assert_allclose(game.features[1:, L:], hidden[:-1].numpy(), atol=1e-5)
    np.testing.assert_allclose(game.last_features[L:], hidden[-1].numpy(), atol=1e-5)
    np.testing.assert_allclose(game.last_features[:L], np.eye(L)[1])  # cell 2 --left--> cell 1


def test_the_own_memory_learns_the_random_rollouts_and_then_the_experts_games(tmp_path):
    """The own-memory variant's latents: the random rollouts unchanged, then each expert game's z
    (its features' first L entries), actions, rewards and end, last, so the memory validates on them."""
    from wmthesis.alphazero.expert_memory import expert_latents, memory_folder
    from wmthesis.world_models.train import LatentStore, split_episodes

    rng = np.random.default_rng(0)
    rollouts = tmp_path / "latents.h5"
    with h5py.File(rollouts, "w") as f:
        f.attrs["identity"] = json.dumps({"env": "corridor"})
        f["mu"] = rng.normal(size=(12, L)).astype(np.float32)
        f["logvar"] = rng.normal(-2, 0.5, size=(12, L)).astype(np.float32)
        f["actions"] = rng.integers(0, A, 12)
        f["rewards"] = np.zeros(12, np.float32)
        f["terminals"] = np.isin(np.arange(12), [4, 11])
        f["episode_ends"] = np.array([5, 12])
    games = [expert_games(Corridor(), lambda agent_seed: ZigZag(turn), vision, LatentMDP(small_memory()), seeds=[0],
                          max_steps=9, progress=False)[0] for turn in (2, 9)]  # the second walks to the goal
    assert [len(g) for g in games] == [9, 4] and [g.terminated for g in games] == [False, True]
    store = LatentStore(expert_latents(rollouts, games, tmp_path / "with-expert.h5", {"env": "corridor", "games": 2}))
    before = LatentStore(rollouts)
    assert len(store) == 4 and store.identity == {"env": "corridor", "games": 2}
    for k in (0, 1):
        for name in ("mu", "logvar", "actions", "rewards", "terminals"):
            np.testing.assert_array_equal(store.episode(k)[name].numpy(), before.episode(k)[name].numpy())
    for k, game in enumerate(games, start=2):
        episode = {name: value.numpy() for name, value in store.episode(k).items()}
        np.testing.assert_array_equal(episode["mu"], game.features[:, :L])
        np.testing.assert_array_equal(episode["actions"], game.actions)
        np.testing.assert_array_equal(episode["rewards"], game.rewards)
        np.testing.assert_array_equal(episode["terminals"], np.arange(len(game)) == len(game) - 1 if game.terminated
                                      else np.zeros(len(game), bool))
        np.testing.assert_allclose(episode["logvar"], np.broadcast_to(before.data["logvar"].numpy().mean(0), (len(game), L)))
    assert games[1].score == 1 and store.episode(3)["rewards"].numpy()[-1] == 1
    assert list(split_episodes(len(store), 0.25)[1]) == [3]  # the memory validates on an expert game
    assert memory_folder(tmp_path, tiny_config()) == tmp_path
    assert memory_folder(tmp_path, tiny_config(memory_games=20)) == tmp_path / "memory-expert-20"


def test_imitation_pretrains_the_heads_to_play_like_the_expert(tmp_path):
    config = tiny_config(**{**VARIANTS.changes("imitation"), "expert_games": 3}, games=0, eval_max_steps=12)
    with pytest.raises(ValueError, match="expert"):
        train_alphazero(Corridor, vision, small_memory(), config, progress=False)
    with pytest.raises(ValueError, match=">= 0"):
        train_alphazero(Corridor, vision, small_memory(), dataclasses.replace(config, expert_games=-1), progress=False,
                        expert=lambda agent_seed: ZigZag())
    run = train_alphazero(Corridor, vision, small_memory(), config, out_dir=tmp_path, progress=False,
                          expert=lambda agent_seed: ZigZag(turn=3))
    assert run.expert["games"] == 3 and run.expert["steps"] == 36 and run.expert["scores"] == [0.0] * 3
    assert run.expert["agreement_before"] < 1 and run.expert["agreement"] == 1.0
    assert run.expert["loss"] < run.expert["loss_before"] and len(run.replay) == 3
    assert agreement(run.heads, list(run.replay)) == 1.0
    # the policy head alone, with the memory's h, walks the expert's path in a new game
    memory = small_memory()
    mind = PolicyHeadMind(vision, LatentMDP(memory), run.heads)
    history = loop(Corridor(), mind, policy="deterministic", callbacks=[mind], max_steps=7, train_mode=False)
    assert history[0]["steps"] == 7
    np.testing.assert_array_equal(mind.recorder.game.actions, [1, 1, 1, 0, 1, 0, 1])
    assert load_run(tmp_path).expert == run.expert  # the checkpoint keeps it, and resuming does not imitate again
    for a, b in zip(load_run(tmp_path).pretrained_heads().parameters(), run.heads.parameters()):
        assert torch.equal(a, b)  # no self-play game: the heads are still the pretrained ones


# ----------------------------------------------------------------------------- the reward model
def sparse_rows(n: int, seed: int) -> tuple:
    """Rows whose reward is +1 on ~3% of them (feature 0 > 1.9 and action 1), -1 on ~3% (feature 1
    > 1.9, any action), else 0: features (n, 6), actions (n,) in 0..2, rewards (n,)."""
    rng = np.random.default_rng(seed)
    x = rng.standard_normal((n, 6)).astype(np.float32)
    a = rng.integers(3, size=n)
    r = np.where((x[:, 0] > 1.9) & (a == 1), 1.0, 0.0) - (x[:, 1] > 1.9)
    return x, a, r.astype(np.float32)


def test_reward_model_learns_a_sparse_action_dependent_reward():
    torch.manual_seed(0)
    model = RewardModel(6, 3, hidden=32, reward_range=2)
    train = sparse_rows(20_000, 0)
    assert 0.01 < (train[2] > 0).mean() < 0.05
    optimiser = torch.optim.Adam(model.parameters(), lr=3e-3)
    train_reward_model(model, optimiser, train, epochs=6, batch_size=256, rng=np.random.default_rng(0))
    fit = reward_fit(model, sparse_rows(5_000, 1))
    assert fit["auc_positive"] > 0.95 and fit["auc_negative"] > 0.95 and fit["corr"] > 0.5
    hit = torch.tensor([[2.5, 0, 0, 0, 0, 0]] * 3)
    with torch.no_grad():
        expected = model.expected(hit, torch.arange(3))
    assert expected[1] > 0.4 and expected[0] < 0.2 and expected[2] < 0.2  # only action 1 earns the +1
    view = RewardView(model)
    assert view(hit[0].numpy(), 1) == pytest.approx(float(expected[1]), abs=1e-5)


def chance_rows(n: int, seed: int) -> tuple:
    """Rows whose rewards the features cannot tell: +1 with probability 0.05, -1 with 0.01:
    features (n, 6), actions (n,) in 0..2, rewards (n,)."""
    rng = np.random.default_rng(seed)
    u = rng.random(n)
    r = np.where(u < 0.05, 1.0, np.where(u > 0.99, -1.0, 0.0)).astype(np.float32)
    return rng.standard_normal((n, 6)).astype(np.float32), rng.integers(3, size=n), r


def test_an_unweighted_reward_model_is_calibrated_and_a_weighted_one_leans_to_rare_rewards():
    """The own-reward variant's search sums expected rewards: they must be calibrated. On
    held-out :func:`chance_rows` (mean reward 0.04), the mean of the expected rewards."""
    train, held_out = chance_rows(20_000, 0), chance_rows(5_000, 1)
    means = {}
    for weighted in (False, True):
        torch.manual_seed(0)
        model = RewardModel(6, 3, hidden=32, reward_range=2)
        optimiser = torch.optim.Adam(model.parameters(), lr=1e-3)
        train_reward_model(model, optimiser, train, 3, 256, np.random.default_rng(0), weighted=weighted)
        with torch.no_grad():
            means[weighted] = float(model.expected(torch.from_numpy(held_out[0]),
                                                   torch.from_numpy(held_out[1]).long()).mean())
    assert means[False] == pytest.approx(0.04, abs=0.01)
    assert means[True] > 0.07  # the weights lift both rare rewards, the commoner +1 most in sum


def test_reward_rows_credit_the_delayed_reward_and_the_mdp_uses_the_model():
    features, actions, rewards = np.arange(10.0).reshape(5, 2), np.arange(5), np.array([0, 0, 1, 0, -1], np.float32)
    x, a, r = reward_rows(features, actions, rewards, delay=2)
    assert np.array_equal(x, features[:3]) and np.array_equal(a, [0, 1, 2]) and np.array_equal(r, [1, 0, -1])
    torch.manual_seed(0)
    model = RewardModel(L + H, A)
    mdp, plain = LatentMDP(small_memory(), model), LatentMDP(small_memory())
    state = plain.initial_state(np.eye(L, dtype=np.float32)[1])
    (next_state, reward), (plain_state, _) = mdp.transition(state, 1), plain.transition(state, 1)
    features = torch.from_numpy(np.concatenate([state.z, state.h]))[None]
    assert reward == pytest.approx(float(model.expected(features, torch.tensor([1])).detach()), abs=1e-5)
    assert np.array_equal(next_state.h, plain_state.h)  # the memory still moves the state


def test_value_targets_of_the_learned_reward_variant_use_the_delayed_rewards():
    config = tiny_config(**{**VARIANTS.changes("learned-reward"), "value_target": "monte-carlo"}, gamma=0.5)
    rewards = np.array([0, 0, 1, 0], np.float32)
    game = type("G", (), {"rewards": rewards})()
    assert np.allclose(game_targets(game, None, config), value_targets([1, 0, 0, 0], 0.5))


class Store:
    """A LatentStore stand-in from arrays: ``episodes`` of ``length`` steps."""

    def __init__(self, mu, actions, rewards, episodes: int):
        self.data = {"mu": torch.tensor(mu), "actions": torch.tensor(actions), "rewards": torch.tensor(rewards)}
        self.ends = np.arange(1, episodes + 1) * (len(actions) // episodes)
        self.starts = self.ends - len(actions) // episodes

    def __len__(self) -> int:
        return len(self.ends)


@pytest.mark.parametrize("action_matters", [True, False])
def test_action_predictability_finds_an_advantage_only_where_there_is_one(action_matters):
    rng = np.random.default_rng(0)
    mu = rng.standard_normal((8000, L)).astype(np.float32)
    actions = rng.integers(A, size=8000)
    pays = (mu[:, 0] > 0) == (actions == 1) if action_matters else mu[:, 0] > 0  # the right action, or the state
    rewards = np.where(pays & (rng.random(8000) < 0.5), 1.0, 0.0).astype(np.float32)
    fit = action_predictability(LatentMDP(small_memory()), Store(mu, actions, rewards, 20), horizons=(1,),
                                epochs=4)["1"]
    if action_matters:
        assert fit["advantage_corr"] > 0.3  # ~0.45 here (half the paying steps pay)
    else:
        assert abs(fit["advantage_corr"]) < 0.15 and fit["v_corr"] > 0.3


def test_evaluation_games_start_with_different_noop_counts():
    from wmthesis.alphazero.replay import game_seeds
    from wmthesis.envs.atari import noop_count
    from wmthesis.alphazero.evaluation import evaluation_seeds

    seeds = evaluation_seeds(0, 10, noop_max=30)
    assert len({noop_count(game_seeds(s)[0], 30) for s in seeds}) == 10  # a greedy agent would replay a repeat
    assert len(evaluation_seeds(0, 5, noop_max=3)) == 5  # more games than no-op counts: repeats allowed
    from wmthesis.alphazero.evaluation import validation_seeds

    counts = lambda seeds: [noop_count(game_seeds(s)[0], 30) for s in seeds]  # noqa: E731
    for seed in (0, 1):
        chosen_on = counts(validation_seeds(seed, 20))
        assert len(set(chosen_on)) == 20 and not set(chosen_on) & set(counts(evaluation_seeds(seed, 10)))
    with pytest.raises(ValueError, match="no-op counts"):
        validation_seeds(0, 21)
    env = NoopStart(Corridor(), noop_max=30)
    for seed in (7, 8):
        env.reset(seed=seed)
        assert env.unwrapped.steps == noop_count(seed, 30)


def test_cached_evaluation_games_are_replayed_when_the_decision_rule_changes(tmp_path, monkeypatch):
    from types import SimpleNamespace

    from wmthesis.alphazero import evaluation

    played = []
    monkeypatch.setattr(evaluation, "boxing_env", lambda noop_max: SimpleNamespace(close=lambda: None))
    monkeypatch.setattr(evaluation, "play", lambda env, mind, seed, k, **kw: played.append(
        mind.config.decision_beta) or SimpleNamespace(frames=None, score=float(k)))
    run = SimpleNamespace(games=4, heads=AlphaZeroHeads(L, H, A), mdp=lambda memory: LatentMDP(memory))
    for beta in (None, None, 5.0, 5.0, None):
        config = tiny_config(eval_episodes=2, decision_beta=beta)
        games = evaluation.evaluation_games(run, vision, small_memory(), config, tmp_path, 0)
        assert [g.score for g in games] == [0.0, 1.0]
    assert played == [None, None, 5.0, 5.0]  # each rule played once, then read from its cache


def test_profiles_keep_the_thesis_values():
    thesis = for_profile(AlphaZeroConfig, "thesis")
    assert (thesis.c, thesis.simulations, thesis.dirichlet_alpha, thesis.noise_ratio, thesis.gamma) == (1.0, 50, 0.3,
                                                                                                      0.25, 0.99)
    assert (thesis.warmup, thesis.replay_games, thesis.train_every, thesis.epochs, thesis.batch_size) == (12, 1000, 10,
                                                                                                       5, 256)
    assert (thesis.lr, thesis.momentum, thesis.l2, thesis.value_target) == (1e-2, 0.9, 1e-4, "monte-carlo")
    assert for_profile(AlphaZeroConfig, "quick").eval_episodes >= 5
    assert not thesis.reward_model and for_profile(AlphaZeroConfig, "quick", **VARIANTS.changes("learned-reward")).reward_model


# ----------------------------------------------------------------------------- the experiment
@pytest.mark.slow
def test_smoke_experiment_writes_metrics_with_finite_scores():
    from wmthesis.alphazero.variants import VARIANTS
    from wmthesis.experiments import reproduce

    default = reproduce("boxing-wm-alphazero", "smoke", progress=False)  # no variant: the default, as everywhere
    assert default["variants"] == [VARIANTS.default.name] == ["own-memory"]
    by_variant = {name: reproduce("boxing-wm-alphazero", "smoke", variant=name, progress=False)
                  for name in ("unchanged", "improved", "learned-reward", "imitation", "own-reward")}
    by_variant["own-memory"] = default
    assert {m["variants"][0] for m in by_variant.values()} == set(VARIANTS)
    names = {"unchanged": ["AlphaZero unchanged"], "improved": ["AlphaZero improved"],
             "learned-reward": ["AlphaZero learned-reward"],
             "imitation": ["AlphaZero imitation", "AlphaZero imitation: policy head alone, no search",
                           "AlphaZero imitation: before self-play (search)"],
             "own-reward": ["AlphaZero own-reward", "AlphaZero own-reward: policy head alone, no search"],
             "own-memory": ["AlphaZero own-memory"]}
    for variant, metrics in by_variant.items():
        for name in [*names[variant], "random"]:
            score = metrics["scores"][name]
            assert np.isfinite(score["mean"]) and score["episodes"] == 2
        assert metrics["runs"][variant]["games"] == 4 and len(metrics["runs"][variant]["rounds"]) == 2
        assert Path(metrics["files"]["figures"][0]).parent.name == variant
    metrics = by_variant["learned-reward"]
    written = json.loads(Path(metrics["files"]["figures"][0]).with_name("metrics.json").read_text())
    assert written["scores"] == json.loads(json.dumps(metrics["scores"]))
    assert all(Path(f).stat().st_size > 1000 for f in metrics["files"]["figures"])
    assert len(metrics["diagnosis"]["reward_error"]["reward_mse"]) == 5
    assert len(metrics["runs"]["learned-reward"]["reward_fits"]) == 3
    assert len(by_variant["own-reward"]["runs"]["own-reward"]["reward_fits"]) == 4  # and once more on the expert's games
    _the_own_memory_is_searched_and_shipped()
    expert = by_variant["imitation"]["runs"]["imitation"]["expert"]
    assert expert["games"] == 8 and expert["steps"] == 8 * 20 and 0 <= expert["agreement"] <= 1
    again = reproduce("boxing-wm-alphazero", "smoke", progress=False)  # cached: evaluates nothing again
    assert again["scores"] == default["scores"]
    # written again by a call that trains nothing: the time it states for a run from scratch counts
    # the world model's and the self-play's sittings before it
    Path(default["files"]["figures"][0]).with_name("metrics.json").unlink()
    fresh = reproduce("boxing-wm-alphazero", "smoke", progress=False)
    played = sum(g["seconds"] for g in default["runs"]["own-memory"]["curve"])
    assert played > 0 and fresh["first_run_wall_seconds"] > fresh["wall_seconds"] + 0.5 * played


def _the_own_memory_is_searched_and_shipped():
    """own-memory's run and its agent file hold the memory that learned the expert's bouts, not the
    random-play memory the other variants search in."""
    from wmthesis.alphazero.agent import load_agent
    from wmthesis.alphazero.selfplay import load_run
    from wmthesis.runs import work_folder

    work = work_folder("smoke", "boxing-wm-alphazero", 0)
    own, base = load_agent(work / "agent-own-memory.pt"), load_agent(work / "agent-own-reward.pt")
    assert (work / "memory-expert-20" / "latents-with-expert.h5").exists()
    assert not np.array_equal(own.mdp.w_gates, base.mdp.w_gates)
    assert load_run(work / "own-memory").task["memory"] != load_run(work / "own-reward").task["memory"]  # the heads learned in the own memory


def test_a_corrupt_cached_result_is_computed_again(tmp_path):
    from wmthesis.runs import read_json

    path = tmp_path / "baselines.json"
    assert read_json(path) is None
    path.write_text('{"key": 1, "returns"')  # cut off mid-write by hand
    assert read_json(path) is None
    path.write_text('{"key": 1}')
    assert read_json(path) == {"key": 1}
