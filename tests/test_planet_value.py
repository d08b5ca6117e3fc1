"""The latent action value (planet.value): its targets by hand, its features as the RSSM's own
transition, and a known answer: in a game where action 1 pays one step later than it is taken
plus one, the value agent learns to take it, and a run resumes where it stopped."""
import dataclasses
import json

import gymnasium as gym
import numpy as np
import pytest
import torch

from wmthesis.config import for_profile
from wmthesis.data import EpisodeStore
from wmthesis.rollouts import play_random_episode
from wmthesis.value.config import LatentValueConfig
from wmthesis.planet.rssm import RSSM
from wmthesis.value.latent_value import (LatentValue, ValueMind, after_action, best_values, episode_features, fit_value,
                                   reward_sums, round_ensemble, td_targets)
from wmthesis.value.play import bout_pool, evaluation_seeds, play_value, play_values, validation_seeds
from wmthesis.value.rounds import as_shipped, best_round, load_value, round_values, train_value

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # see conftest.py


class DelayedPunch(gym.Env):
    """A blank 64x64 screen; action 1 (of 3) scores 1 two steps after it is taken, like a
    Boxing punch; 24 steps an episode."""

    observation_space = gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)
    action_space = gym.spaces.Discrete(3)

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.history, self.t = [0, 0], 0
        return np.zeros((64, 64, 3), np.uint8), {}

    def step(self, action):
        self.history.append(int(action))
        self.t += 1
        reward = float(self.history[-3] == 1)
        return np.zeros((64, 64, 3), np.uint8), reward, False, self.t >= 24, {}


def frozen_rssm() -> RSSM:
    torch.manual_seed(0)
    return RSSM(3, belief_size=16, state_size=4, hidden_size=16, reward_hidden_size=8).eval()


def test_reward_sums_by_hand():
    rewards = np.array([1, 0, 0, -1, 0, 2], np.float32)
    assert reward_sums(rewards, 3).tolist() == [1, -1, -1, 1, 2, 2]
    assert reward_sums(rewards, 1).tolist() == rewards.tolist()
    with pytest.raises(ValueError, match="reward_steps"):
        reward_sums(rewards, 0)


def test_features_are_the_transition_after_each_action_and_depend_on_it():
    model = frozen_rssm()
    belief, state = torch.randn(3, 16), torch.randn(3, 4)
    with torch.no_grad():
        features = after_action(model, belief, state, torch.arange(3))
        expected_belief, prior = model.transition(belief, state, torch.eye(3))
    assert torch.equal(features, torch.cat([expected_belief, prior.mean], -1))
    assert not torch.allclose(features[0], features[1])
    episode = play_random_episode(DelayedPunch(), 0, 0)
    assert episode_features(model, episode, 5, 0).shape == (24, 20)


def test_value_agent_learns_the_delayed_punch_and_resumes(tmp_path):
    model, env = frozen_rssm(), DelayedPunch()
    config = LatentValueConfig(hidden_size=32, random_bouts=20, fit_updates=300, batch_size=64, rounds=1,
                               bouts_per_round=2, test_bouts=2)
    first = train_value(model, 5, env, dataclasses.replace(config, rounds=0), tmp_path, seed=0, progress=False)
    assert len(first["curve"]) == 1 and first["curve"][0]["episodes"] == 0
    result = train_value(model, 5, env, config, tmp_path, seed=0, progress=False)
    curve = result["curve"]
    assert [c["round"] for c in curve] == [0, 1] and curve[0] == first["curve"][0]  # round 0 kept, not redone
    with EpisodeStore(tmp_path / "episodes.h5") as store:
        assert len(store) == 22 and curve[1]["episodes"] == 2
        random_returns = [store.episode(i)["rewards"].sum() for i in range(20)]
    # Always punching scores 22 of 24 steps; random play about a third of that.
    assert all(r == 22 for r in curve[-1]["returns"]) and max(random_returns) < 15
    with pytest.raises(ValueError, match="hidden_size: 32 -> 16"):  # a changed config is not resumed
        train_value(model, 5, env, dataclasses.replace(config, hidden_size=16), tmp_path, seed=0, progress=False)
    value = load_value(tmp_path, model)
    scores = ValueMind(model, value).plan(np.zeros((64, 64, 3), np.uint8))
    assert scores.argmax() == 1 and scores[1] - max(scores[0], scores[2]) > 0.5


class PreferTwo(torch.nn.Module):
    """A value that prefers action 2 in every state."""

    def forward(self, features):
        return features.new_tensor([0.0, 0.0, 1.0])


def test_epsilon_greedy_play_explores():
    model, env = frozen_rssm(), DelayedPunch()
    greedy = play_value(env, model, PreferTwo(), 5, 0, 0)["actions"]
    noisy = play_value(env, model, PreferTwo(), 5, 0, 0, epsilon=0.5)["actions"]
    assert set(greedy.tolist()) == {2} and len(set(noisy.tolist())) == 3


def test_profiles_and_missing_value(tmp_path):
    smoke = for_profile(LatentValueConfig, "smoke")
    assert smoke.rounds < LatentValueConfig().rounds and smoke.fit_updates < LatentValueConfig().fit_updates
    with pytest.raises(FileNotFoundError, match="train_value"):
        load_value(tmp_path, frozen_rssm())
    torch.save({"value": {}, "curve": [], "config": {}}, tmp_path / "value.pt")  # a run of session 14's format
    with pytest.raises(ValueError, match="before values were chosen"):
        load_value(tmp_path, frozen_rssm())


def test_an_ensemble_averages_its_heads_and_fits_each():
    torch.manual_seed(0)
    value = LatentValue(6, 32, heads=3)
    features = torch.randn(512, 6)
    targets = 2 * features[:, 0] - features[:, 3]
    assert torch.allclose(value(features), value.each(features).mean(-1))
    before = value.each(features)
    assert not torch.allclose(before[:, 0], before[:, 1])  # each head starts on its own
    config = LatentValueConfig(fit_updates=400, batch_size=64, lr=3e-3)
    loss = fit_value(value, features, targets, config, seed=0)
    with torch.no_grad():
        errors = ((value.each(features) - targets[:, None]) ** 2).mean(0)
    assert loss < 0.05 and (errors < 0.05).all()  # every head learnt the target, not just their mean
    with pytest.raises(ValueError, match="heads"):
        LatentValue(6, 32, heads=0)


def test_best_round_is_chosen_on_validation_and_kept(tmp_path):
    assert best_round([{"round": 0, "validation_mean": 1.0}, {"round": 1, "validation_mean": 3.0},
                       {"round": 2, "validation_mean": 3.0}, {"round": 3, "validation_mean": 2.0}]) == 1
    # Values fitted with one step differ from round to round; the kept one is the validation's best.
    model, env = frozen_rssm(), DelayedPunch()
    config = LatentValueConfig(hidden_size=8, random_bouts=2, fit_updates=1, batch_size=8, lr=0.03, rounds=3,
                               bouts_per_round=1, validation_bouts=2, test_bouts=2)
    curve = train_value(model, 5, env, config, tmp_path, seed=0, progress=False)["curve"]
    best = best_round(curve)
    assert all(len(entry["validation"]) == 2 for entry in curve)
    assert best != curve[-1]["round"] and curve[best]["validation"] != curve[-1]["validation"]
    value = load_value(tmp_path, model)  # the best round's value, not the last
    assert [play_value(env, model, value, 5, *validation_seeds(0, k))["rewards"].sum() for k in range(2)] \
        == curve[best]["validation"]
    assert [play_value(env, model, value, 5, *evaluation_seeds(0, k))["rewards"].sum() for k in range(2)] \
        == curve[best]["returns"]
    assert validation_seeds(0, 0) != evaluation_seeds(0, 0)
    # a value belongs to its model: another model's weights are refused, on load and on resume
    other = RSSM(3, belief_size=16, state_size=4, hidden_size=16, reward_hidden_size=8).eval()
    with pytest.raises(ValueError, match="was fitted on another model"):
        load_value(tmp_path, other)
    with pytest.raises(ValueError, match="was fitted on another model"):
        train_value(other, 5, env, dataclasses.replace(config, rounds=4), tmp_path, seed=0, progress=False)


def test_a_nan_in_the_value_loss_stops_before_that_update():
    from wmthesis.training import NonFiniteLoss

    torch.manual_seed(0)
    value, config = LatentValue(6, 8, heads=2), LatentValueConfig(fit_updates=5, batch_size=4)
    features, targets = torch.randn(10, 6), torch.randn(10)
    targets[3:] = float("nan")  # 7 of 10 targets: the first batches (seeded) draw one
    before = [p.detach().clone() for p in value.parameters()]
    with pytest.raises(NonFiniteLoss, match="latent value: non-finite loss term loss = nan at update 1"):
        fit_value(value, features, targets, config, seed=0)
    assert all(torch.equal(a, b) for a, b in zip(before, value.parameters()))  # no weight changed


def test_td_targets_by_hand_discounted_rewards_then_the_best_value_n_steps_on():
    rewards = np.array([1.0, 0.0, 2.0, 0.0, 1.0], np.float32)
    sums = reward_sums(rewards, 2, 0.5)  # r_t + 0.5 r_{t+1}
    assert sums.tolist() == [1.0, 1.0, 2.0, 0.5, 1.0]
    values = torch.tensor([9.0, 8.0, 7.0, 6.0, 5.0])
    targets = td_targets(torch.as_tensor(sums), values, 2, 0.5)  # + 0.25 max_a Q two steps on, 0 past the end
    assert targets.tolist() == [1.0 + 0.25 * 7, 1.0 + 0.25 * 6, 2.0 + 0.25 * 5, 0.5, 1.0]


def test_best_values_are_the_max_over_every_action_through_the_model():
    model = frozen_rssm()
    value = LatentValue(20, 8, heads=2)
    beliefs, states = torch.randn(7, 16), torch.randn(7, 4)
    with torch.no_grad():
        by_hand = torch.stack([value(after_action(model, beliefs[i].expand(3, -1), states[i].expand(3, -1),
                                                  torch.arange(3))).max() for i in range(7)])
    assert torch.allclose(best_values(model, value, beliefs, states, chunk=3), by_hand, atol=1e-6)


class Walk(gym.Env):
    """Seven cells in a row, drawn as a bright column; action 0 steps left, 1 stays, 2 steps
    right; every step on the last cell scores 1, and a step left against the wall of the first
    scores 0.1; 24 steps from the first cell. The large reward is 6 steps away: a value that
    sums 3 rewards sees only the small one from the start, one that bootstraps sees both."""

    observation_space = gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)
    action_space = gym.spaces.Discrete(3)

    def frame(self):
        frame = np.zeros((64, 64, 3), np.uint8)
        frame[:, 9 * self.cell:9 * self.cell + 8] = 255
        return frame

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.cell, self.t = 0, 0
        return self.frame(), {}

    def step(self, action):
        against_the_wall = self.cell == 0 and int(action) == 0
        self.cell = int(np.clip(self.cell + int(action) - 1, 0, 6))
        self.t += 1
        return self.frame(), float(self.cell == 6) + 0.1 * against_the_wall, False, self.t >= 24, {}


def test_a_td_value_looks_past_its_rewards_where_the_sum_of_three_cannot(tmp_path):
    model, env = frozen_rssm(), Walk()
    config = LatentValueConfig(hidden_size=64, heads=2, random_bouts=40, fit_updates=1500, batch_size=128, lr=3e-3,
                               rounds=0, validation_bouts=1, test_bouts=1, reward_steps=3)
    td = train_value(model, 5, env, dataclasses.replace(config, target="td", discount=0.9, td_iterations=6),
                     tmp_path / "td", seed=0, progress=False)
    summed = train_value(model, 5, env, config, tmp_path / "sum", seed=0, progress=False)
    assert td["curve"][0]["returns"][0] >= 15  # walks right at once: 18 of 24 steps on the last cell
    assert summed["curve"][0]["returns"][0] < 5  # stays by the wall for the small reward (2.4 in all)
    with pytest.raises(ValueError, match="unknown value target 'mc'; valid: reward-sum, discounted-sum, log-discounted-sum, td"):
        train_value(model, 5, env, dataclasses.replace(config, target="mc"), tmp_path / "x", seed=0, progress=False)


def test_a_variant_that_adds_rounds_starts_from_a_copy_and_matches_a_run_from_scratch(tmp_path):
    from wmthesis.value.comparison import start_from

    model, env = frozen_rssm(), DelayedPunch()
    config = LatentValueConfig(hidden_size=8, random_bouts=2, fit_updates=2, batch_size=8, lr=0.03, rounds=1,
                               bouts_per_round=1, validation_bouts=1, test_bouts=1)
    train_value(model, 5, env, config, tmp_path / "default", seed=0, progress=False)
    more = dataclasses.replace(config, rounds=2)
    start_from(tmp_path / "variant", tmp_path / "default")
    copied = train_value(model, 5, env, more, tmp_path / "variant", seed=0, progress=False)["curve"]
    scratch = train_value(model, 5, env, more, tmp_path / "scratch", seed=0, progress=False)["curve"]
    strip = [{k: v for k, v in c.items() if k != "loss"} for c in scratch]
    assert len(copied) == 3 and [{k: v for k, v in c.items() if k != "loss"} for c in copied] == strip
    assert [c["loss"] for c in copied] == pytest.approx([c["loss"] for c in scratch])
    # once the variant has a checkpoint of its own, the default's is never copied over it
    before = (tmp_path / "variant" / "value.pt").read_bytes()
    start_from(tmp_path / "variant", tmp_path / "default")
    assert (tmp_path / "variant" / "value.pt").read_bytes() == before


def test_the_discounted_sum_target_discounts_each_reward_and_the_plain_sum_does_not(tmp_path):
    from wmthesis.value.rounds import value_dataset

    model, env = frozen_rssm(), DelayedPunch()
    with EpisodeStore(tmp_path / "episodes.h5", "a", preprocessing="planet", seed=0,
                      obs_shape=env.observation_space.shape) as store:
        for index in range(2):
            store.append_episode(**play_random_episode(env, 0, index))
        rewards = [store.episode(i)["rewards"] for i in range(2)]
    assert any(r.sum() > 0 for r in rewards)
    base = LatentValueConfig(reward_steps=4, discount=0.5)
    discounted = value_dataset(model, tmp_path / "episodes.h5", dataclasses.replace(base, target="discounted-sum"), 5, [])
    plain = value_dataset(model, tmp_path / "episodes.h5", base, 5, [])
    for r, d, p in zip(rewards, discounted, plain):
        by_hand = [sum(0.5 ** k * r[t + k] for k in range(4) if t + k < len(r)) for t in range(len(r))]
        assert np.allclose(d["sums"].numpy(), by_hand) and np.allclose(p["sums"].numpy(), reward_sums(r, 4))
    logged = value_dataset(model, tmp_path / "episodes.h5", dataclasses.replace(base, target="log-discounted-sum"), 5, [])
    for d, g in zip(discounted, logged):  # floored at a reward just past the window, 0.5^4
        assert np.allclose(g["sums"].numpy(), np.log(d["sums"].numpy() + 0.5 ** 4))


def test_a_log_value_fits_the_logarithm_and_gives_q_on_the_scale_of_rewards(tmp_path):
    from wmthesis.value.latent_value import log_scaled

    torch.manual_seed(0)
    plain, logged = LatentValue(6, 8, heads=2), LatentValue(6, 8, heads=2, log=True)
    logged.load_state_dict(plain.state_dict())
    features = torch.randn(5, 6)
    with torch.no_grad():
        assert torch.allclose(logged(features), plain(features).exp())  # the exponential of the heads' mean
        assert torch.equal(logged.each(features), plain.each(features))  # the heads fit the logarithm
        ensemble = round_ensemble([plain.state_dict(), LatentValue(6, 8, heads=2).state_dict()], 8, log=True)
        assert ensemble.log and torch.allclose(ensemble(features), ensemble.each(features).mean(-1).exp())
    assert log_scaled({"target": "log-discounted-sum"}) and not log_scaled(LatentValueConfig()) and not log_scaled({})
    # a run with the log target keeps it: its agent, loaded, is on the scale of rewards
    model, env = frozen_rssm(), DelayedPunch()
    config = LatentValueConfig(hidden_size=8, random_bouts=2, fit_updates=3, batch_size=8, lr=0.03, rounds=1,
                               bouts_per_round=1, validation_bouts=1, test_bouts=1, target="log-discounted-sum",
                               reward_steps=4, discount=0.5)
    train_value(model, 5, env, config, tmp_path, seed=0, progress=False)
    value = load_value(tmp_path, model)
    with torch.no_grad():
        assert value.log and (value(torch.randn(4, 20)) > 0).all()
    mean = train_value(model, 5, env, dataclasses.replace(config, agent_rounds=2), tmp_path, seed=0, progress=False)
    assert mean["agent"]["rounds"] == [0, 1] and load_value(tmp_path, model).log  # the mean of rounds, logged too


def test_every_round_is_kept_and_a_run_saved_without_them_refits_the_same_values(tmp_path):
    model, env = frozen_rssm(), DelayedPunch()
    config = LatentValueConfig(hidden_size=8, random_bouts=2, fit_updates=3, batch_size=8, lr=0.03, rounds=2,
                               bouts_per_round=1, validation_bouts=1, test_bouts=1)
    curve = train_value(model, 5, env, config, tmp_path, seed=0, progress=False)["curve"]
    saved = torch.load(tmp_path / "value.pt", weights_only=False)
    kept = saved["rounds"]
    assert sorted(kept) == [0, 1, 2] and all(torch.equal(saved["value"][k], kept[2][k]) for k in kept[2])
    assert all(torch.equal(saved["best"][k], kept[best_round(curve)][k]) for k in kept[0])
    assert not torch.equal(kept[0]["heads.0.0.weight"], kept[1]["heads.0.0.weight"])  # each fit moved it
    # a run of the earlier format (no rounds kept): refitted from its store, the same values, kept
    torch.save({k: v for k, v in saved.items() if k != "rounds"}, tmp_path / "value.pt")
    refitted = round_values(model, 5, tmp_path, seed=0, progress=False)
    assert all(torch.equal(refitted[r][k], kept[r][k]) for r in kept for k in kept[r])
    assert sorted(torch.load(tmp_path / "value.pt", weights_only=False)["rounds"]) == [0, 1, 2]
    # refitting with another seed is another computation: its losses differ from the saved ones
    torch.save({k: v for k, v in saved.items() if k != "rounds"}, tmp_path / "value.pt")
    with pytest.raises(ValueError, match="refitting round 0 gave loss"):
        round_values(model, 5, tmp_path, seed=1, progress=False)


def test_a_round_ensemble_is_the_mean_of_the_rounds_values():
    torch.manual_seed(0)
    values = [LatentValue(6, 8, heads=2) for _ in range(3)]
    ensemble = round_ensemble([v.state_dict() for v in values], 8)
    features = torch.randn(5, 6)
    with torch.no_grad():
        expected = torch.stack([v(features) for v in values]).mean(0)
        assert len(ensemble.heads) == 6 and torch.allclose(ensemble(features), expected)
        assert torch.allclose(round_ensemble([values[1].state_dict()], 8)(features), values[1](features))
    with pytest.raises(ValueError, match="at least one"):
        round_ensemble([], 8)


def test_the_agent_can_be_the_mean_of_the_last_rounds_values_played_once(tmp_path, monkeypatch):
    import wmthesis.value.rounds as value_module

    model, env = frozen_rssm(), DelayedPunch()
    config = LatentValueConfig(hidden_size=8, random_bouts=2, fit_updates=3, batch_size=8, lr=0.03, rounds=3,
                               bouts_per_round=1, validation_bouts=2, test_bouts=2)
    chosen = train_value(model, 5, env, config, tmp_path, seed=0, progress=False)
    assert chosen["agent"]["rounds"] == [chosen["best_round"]]
    assert chosen["agent"]["returns"] == chosen["curve"][chosen["best_round"]]["returns"]
    # the same rounds, the agent now the mean of the last two: no refit, and it plays the same bouts
    mean = train_value(model, 5, env, dataclasses.replace(config, agent_rounds=2), tmp_path, seed=0, progress=False)
    assert mean["curve"] == chosen["curve"] and mean["agent"]["rounds"] == [2, 3]
    rounds = torch.load(tmp_path / "value.pt", weights_only=False)["rounds"]
    fitted = round_ensemble([rounds[2], rounds[3]], 8)
    ensemble = as_shipped(round_ensemble([rounds[2], rounds[3]], 8))  # the agent as it ships: half-precision weights
    assert all(torch.equal(w, w.half().float()) for w in ensemble.parameters())
    assert not all(torch.equal(a, b) for a, b in zip(ensemble.parameters(), fitted.parameters()))
    assert mean["agent"]["returns"] == [play_value(env, model, ensemble, 5, *evaluation_seeds(0, k))["rewards"].sum()
                                        for k in range(2)]
    features = torch.randn(4, 20)
    with torch.no_grad():
        assert torch.equal(load_value(tmp_path, model)(features), ensemble(features))
    monkeypatch.setattr(value_module, "_scores", lambda *a, **k: pytest.fail("the agent's bouts were played again"))
    again = train_value(model, 5, env, dataclasses.replace(config, agent_rounds=2), tmp_path, seed=0, progress=False)
    assert again["agent"] == mean["agent"]
    # back to the round chosen on validation: load_value gives that round's value again
    train_value(model, 5, env, config, tmp_path, seed=0, progress=False)
    best = LatentValue(20, 8, config.heads)
    best.load_state_dict(rounds[chosen["best_round"]])
    with torch.no_grad():
        assert torch.equal(load_value(tmp_path, model)(features), as_shipped(best)(features))
    with pytest.raises(ValueError, match="agent_rounds"):
        train_value(model, 5, env, dataclasses.replace(config, agent_rounds=-1), tmp_path, seed=0, progress=False)


def test_bouts_in_a_pool_of_processes_are_the_bouts_played_here_stored_in_order(monkeypatch):
    monkeypatch.setenv("WMTHESIS_PROCESSES", "2")  # the pool of a 2-core machine (the suite runs as on one)
    model, env = frozen_rssm(), DelayedPunch()
    torch.manual_seed(1)
    value = LatentValue(20, 8, heads=2)
    seeds = [evaluation_seeds(0, k) for k in range(5)]
    here = play_values(env, model, value, 5, seeds, epsilon=0.5)
    order = []
    with bout_pool(model, (DelayedPunch,)) as pool:
        assert pool is not None  # two processes
        there = play_values(env, model, value, 5, seeds, epsilon=0.5, pool=pool,
                            on_done=lambda index, episode: order.append((index, episode["actions"].tolist())))
    assert order == [(k, episode["actions"].tolist()) for k, episode in enumerate(here)]
    for a, b in zip(here, there):
        assert set(a) == set(b) and all(np.array_equal(a[key], b[key]) for key in a)
    assert len({tuple(episode["actions"]) for episode in here}) > 1  # each bout seeded by its own pair
    with bout_pool(model, None) as pool:
        assert pool is None


def test_a_lean_run_fits_the_same_rounds_without_their_bouts_and_scores_only_its_agent(tmp_path, monkeypatch):
    import wmthesis.value.rounds as value_module

    model, env = frozen_rssm(), DelayedPunch()
    config = LatentValueConfig(hidden_size=8, random_bouts=2, fit_updates=3, batch_size=8, lr=0.03, rounds=3,
                               bouts_per_round=2, validation_bouts=2, test_bouts=2, agent_rounds=2)
    scored = train_value(model, 5, env, config, tmp_path / "scored", seed=0, progress=False)
    played = []
    greedy = value_module.greedy_returns
    monkeypatch.setattr(value_module, "greedy_returns", lambda *a, **k: played.append(len(a[4])) or greedy(*a, **k))
    lean = train_value(model, 5, env, dataclasses.replace(config, score_rounds=False), tmp_path / "lean", seed=0,
                       progress=False, make_env=(DelayedPunch,))
    assert played == [2]  # the agent's test bouts only: no validation, no bouts after each round
    assert [set(entry) for entry in lean["curve"]] == [{"round", "episodes", "loss"}] * 4
    assert [e["loss"] for e in lean["curve"]] == [e["loss"] for e in scored["curve"]]  # the same fits
    assert lean["best_round"] is None and lean["agent"]["rounds"] == [2, 3] == scored["agent"]["rounds"]
    assert lean["agent"]["returns"] == scored["agent"]["returns"]  # and the same agent on the same bouts
    assert "validation" not in lean["agent"]
    features = torch.randn(4, 20)
    with torch.no_grad():
        assert torch.equal(load_value(tmp_path / "lean", model)(features), load_value(tmp_path / "scored", model)(features))
    with pytest.raises(ValueError, match="score_rounds=False needs agent_rounds"):
        train_value(model, 5, env, dataclasses.replace(config, score_rounds=False, agent_rounds=0), tmp_path / "x",
                    seed=0, progress=False)
    with pytest.raises(ValueError, match="another LatentValueConfig.*score_rounds"):
        train_value(model, 5, env, config, tmp_path / "lean", seed=0, progress=False)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs a GPU")
def test_a_model_on_the_gpu_plays_its_bouts_in_this_process_and_learns_as_on_the_cpu(tmp_path):
    model, env = frozen_rssm().cuda(), DelayedPunch()
    with bout_pool(model, (DelayedPunch,)) as pool:
        assert pool is None  # a CUDA model is not sent to processes of its own
    config = LatentValueConfig(hidden_size=32, random_bouts=20, fit_updates=300, batch_size=64, rounds=2,
                               bouts_per_round=2, test_bouts=3, agent_rounds=2, score_rounds=False)
    run = train_value(model, 5, env, config, tmp_path, seed=0, progress=False, make_env=(DelayedPunch,))
    assert run["agent"]["rounds"] == [1, 2] and run["agent"]["returns"] == [22.0] * 3  # always punching
    assert next(load_value(tmp_path, model).parameters()).is_cuda


def test_the_value_curve_is_drawn_from_a_run_s_metrics_alone():
    """A value run's figure comes from its metrics as ``metrics.json`` holds them (what a fresh
    clone has): the scored rounds as the line, the agent as the mean of its rounds, and the
    baselines, CEM with the value and the references as labelled lines at their scores."""
    from wmthesis.value.comparison import value_curve_figure

    full = lambda mean: {"full": {"mean": mean}}  # noqa: E731
    metrics = {"env": "boxing", "agent_rounds": [2, 3], "value": {"mean": 7.0, "std": 1.0},
               "curve": [{"round": 0, "episodes": 0, "loss": 1.0}, {"round": 1, "episodes": 20, "mean": 4.0, "std": 2.0},
                         {"round": 2, "episodes": 40, "mean": 6.0, "std": 2.0}, {"round": 3, "episodes": 60, "loss": 0.5}],
               "baselines": {"random": full(-1.0), "planet": full(2.0)},
               "value_planner": {"config": {"horizon": 3}, **full(9.0)}}
    ax = value_curve_figure(json.loads(json.dumps(metrics)), {"human": 12.1}).axes[0]
    scored, agent = (line for line in ax.lines if line.get_marker() == ".")
    assert list(scored.get_xdata()) == [20, 40] and list(scored.get_ydata()) == [4.0, 6.0]
    assert list(agent.get_xdata()) == [60] and list(agent.get_ydata()) == [7.0]
    labels = {t.get_text(): t.xy[1] for t in ax.texts}
    assert labels == {"random play": -1.0, "PlaNet (CEM)": 2.0, "CEM, H3, with the value at its end": 9.0, "human": 12.1}
    earlier = {**{k: v for k, v in metrics.items() if k != "agent_rounds"}, "best_round": 2}  # a run of 26 November
    ax = value_curve_figure(earlier, {}).axes[0]
    assert [list(line.get_ydata()) for line in ax.lines if line.get_marker() == "."] == [[4.0, 6.0]]  # one round: no mean
    assert ax.get_title() == "Boxing: the value agent after each round"
    lean = {**metrics, "curve": [{k: v for k, v in e.items() if k not in ("mean", "std")} for e in metrics["curve"]]}
    ax = value_curve_figure(lean, {"human": 12.1}).axes[0]  # a lean run scores no round: its agent beside the lines
    rows = {t.get_text(): tick for tick, t in enumerate(ax.get_yticklabels())}
    assert list(rows) == ["random play", "PlaNet (CEM)", "the value agent (mean of rounds 2-3)",
                          "CEM, H3, with the value at its end", "human"]  # by score, best at the top
    assert {t.get_text(): t.xy for t in ax.texts} == {f"{x:.1f}": (x, y) for x, y in
                                                      [(-1.0, 0), (2.0, 1), (7.0, 2), (9.0, 3), (12.1, 4)]}


def test_imagined_features_follow_the_actions_taken_from_each_posterior_and_their_signal_is_a_correlation():
    from wmthesis.value.signal import imagined_features, value_signal

    model, value = frozen_rssm(), LatentValue(20, 16, heads=2).eval()
    beliefs, states, actions = torch.randn(5, 16), torch.randn(5, 4), torch.tensor([0, 2, 1, 1, 0])
    with torch.no_grad():
        assert torch.equal(imagined_features(model, beliefs, states, actions, 0),
                           after_action(model, beliefs, states, actions))
        h, prior = model.transition(beliefs[:3], states[:3], torch.eye(3)[actions[:3]])
        h, prior = model.transition(h, prior.mean, torch.eye(3)[actions[1:4]])  # the prior's mean, no draws
        assert torch.allclose(imagined_features(model, beliefs, states, actions, 2),
                              after_action(model, h, prior.mean, actions[2:]))
        drawn = imagined_features(model, beliefs, states, actions, 2, torch.Generator().manual_seed(0))
        assert drawn.shape == (3, 20) and not torch.allclose(drawn, after_action(model, h, prior.mean, actions[2:]))
    for depth in (-1, 1.5, True):
        with pytest.raises(ValueError, match="depth"):
            imagined_features(model, beliefs, states, actions, depth)
    with torch.no_grad():  # deeper than the episode: no step to read
        assert imagined_features(model, beliefs, states, actions, 7).shape == (0, 20)
    episodes = [play_random_episode(DelayedPunch(), 0, k) for k in range(2)]
    signal = value_signal(model, value, episodes, 5, depths=(0, 1))
    with torch.no_grad():
        q = np.concatenate([value(episode_features(model, e, 5, k)).numpy() for k, e in enumerate(episodes)])
    sums = np.concatenate([reward_sums(e["rewards"], 3) for e in episodes])
    assert signal[0] == pytest.approx(np.corrcoef(q, sums)[0, 1], abs=1e-5) and set(signal) == {0, 1}
    assert signal[1] != pytest.approx(signal[0], abs=1e-4)


def test_a_seeds_value_signal_is_kept_and_read_back_and_a_missing_value_run_says_how_to_fit_it(monkeypatch):
    import matplotlib

    matplotlib.use("Agg")
    from wmthesis import runs as run_store
    from wmthesis.value import signal as imagination

    seed = 917  # no run of this seed exists in the tests' data
    with pytest.raises(FileNotFoundError, match="reproduce planet-boxing-value --profile smoke --seed 917"):
        imagination.seed_value_signal("smoke", seed)
    path = run_store.results_folder("planning-budget", "smoke", seed) / "value_signal.json"
    run_store.write_json(path, {"version": imagination.SIGNAL_VERSION, "models": imagination.signal_models("smoke", seed),
                                "depths": [0, 1], "bouts": 20, "steps": 100, "correlation": {"0": 0.3, "1": 0.1}})
    monkeypatch.setattr(imagination, "planner_model", lambda *a: pytest.fail("the kept signal is measured again"))
    assert imagination.seed_value_signal("smoke", seed, depths=(0, 1)) == {0: 0.3, 1: 0.1}
    with pytest.raises(FileNotFoundError):  # other depths: measured anew, and there is no run to measure
        imagination.seed_value_signal("smoke", seed, depths=(0, 1, 2))
    for corrupt in ("{not json", '{"depths": [0, 1], "bouts": 20}'):  # cut off mid-write, or missing its numbers
        path.write_text(corrupt)
        with pytest.raises(FileNotFoundError):  # read as absent: measured anew
            imagination.seed_value_signal("smoke", seed, depths=(0, 1))
    figure = imagination.plot_value_signal({0: {0: 0.3, 1: 0.1}, 1: {0: 0.4, 1: 0.2}})
    lines = figure.axes[0].get_lines()
    assert [line.get_label() for line in lines][:3] == ["seed 0", "seed 1", "mean"]
    assert np.allclose(lines[2].get_ydata(), [0.35, 0.15])
