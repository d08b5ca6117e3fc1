"""Exploration by ensemble disagreement (Plan2Explore) for PlaNet's collecting planner: the bonus
against a hand computation, reduction to the thesis's CEM, the bonus off the data, and the
training loop with an ensemble (the RSSM's updates unchanged, checkpoints that resume)."""
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from wmthesis.config import for_profile
from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.explore import Disagreement, disagreement_loss, explored_returns, one_step_batch
from wmthesis.planet.rssm import RSSM
from wmthesis.planet.agent import PlanetMind
from wmthesis.planet.train import load_planet, train_planet

SMOKE = for_profile(PlaNetConfig, "smoke")
pytestmark = pytest.mark.usefixtures("one_torch_thread")  # see conftest.py


def tiny_rssm(n_actions=3, seed=0) -> RSSM:
    torch.manual_seed(seed)
    return RSSM(n_actions, belief_size=8, state_size=3, hidden_size=8, reward_hidden_size=8)


def test_disagreement_is_the_heads_variance_averaged_over_features():
    torch.manual_seed(0)
    ensemble = Disagreement(features=4, n_actions=2, embedding=3, hidden=5, heads=3)
    features, actions = torch.randn(6, 4), F.one_hot(torch.tensor([0, 1, 1, 0, 1, 0]), 2).float()
    outputs = [head(torch.cat([features, actions], -1)) for head in ensemble.heads]  # 3 x (6, 3)
    mean = sum(outputs) / 3
    by_hand = sum((o - mean) ** 2 for o in outputs).sum(-1) / (2 * 3)  # unbiased over heads, mean over features
    assert torch.allclose(ensemble(features, actions), by_hand, atol=1e-6)
    for head in ensemble.heads[1:]:  # heads that agree disagree by nothing
        head.load_state_dict(ensemble.heads[0].state_dict())
    assert ensemble(features, actions).abs().max() < 1e-12
    targets = torch.randn(6, 3)
    loss = disagreement_loss(ensemble, features, actions, targets)
    assert torch.isclose(loss, 3 * ((outputs[0] - targets) ** 2).mean(), atol=1e-6)
    with pytest.raises(ValueError, match="at least 2 heads"):
        Disagreement(4, 2, 3, heads=1)


def test_without_a_bonus_the_planner_is_the_thesis_cem_and_with_one_it_adds_scale_times_the_bonus():
    model = tiny_rssm(n_actions=4)
    ensemble = Disagreement(8 + 3, 4, embedding=5, hidden=6, heads=4)
    actions = F.one_hot(torch.randint(0, 4, (30, 5), generator=torch.Generator().manual_seed(1)), 4).float()
    belief, state = torch.randn(1, 8), torch.randn(1, 3)
    with torch.no_grad():
        thesis = model.imagined_returns(belief, state, actions, torch.Generator().manual_seed(2))
        assert torch.equal(explored_returns(model, ensemble, 0.0, belief, state, actions,
                                            torch.Generator().manual_seed(2)), thesis)
        explored = explored_returns(model, ensemble, 2.5, belief, state, actions, torch.Generator().manual_seed(2))
        # the same sampled path by hand: each step's bonus from the state before the action
        generator, h, s = torch.Generator().manual_seed(2), belief.expand(30, -1), state.expand(30, -1)
        bonus = torch.zeros(30)
        for t in range(5):
            bonus += ensemble(torch.cat([h, s], -1), actions[:, t])
            h, prior = model.transition(h, s, actions[:, t])
            s = prior.sample(generator)
    assert torch.allclose(explored - thesis, 2.5 * bonus, atol=1e-5) and (bonus > 0).all()
    # the collecting mind plans with the bonus; the config's mind without an explorer, as the thesis
    config = SMOKE.__class__(**{**SMOKE.__dict__, "explore_scale": 2.5})
    frame = np.zeros((64, 64, 3), np.uint8)
    plain, exploring = PlanetMind.from_config(model, config, 7), PlanetMind.from_config(model, config, 7, ensemble)
    assert plain.explore_scale == 0 and exploring.explore_scale == 2.5
    plain.observe(frame), exploring.observe(frame)
    with torch.inference_mode():
        exploring.generator.manual_seed(3), plain.generator.manual_seed(3)
        gained = exploring.returns(actions) - plain.returns(actions)
        by_hand = (explored_returns(model, ensemble, 2.5, exploring.belief, exploring.state, actions,
                                    torch.Generator().manual_seed(3))
                   - model.imagined_returns(exploring.belief, exploring.state, actions, torch.Generator().manual_seed(3)))
    assert torch.allclose(gained, by_hand, atol=1e-5) and (gained > 0).all()


def test_the_bonus_is_larger_off_the_data_than_on_it():
    """Heads trained on one region of feature space agree there and part far from it."""
    torch.manual_seed(0)
    ensemble = Disagreement(features=4, n_actions=2, embedding=3, hidden=32, heads=5)
    optimizer = torch.optim.Adam(ensemble.parameters(), lr=1e-2)
    features = torch.rand(256, 4) * 0.5
    actions = F.one_hot(torch.randint(0, 2, (256,)), 2).float()
    targets = torch.stack([features.sum(-1), features[:, 0] - features[:, 1], actions[:, 0]], -1)
    for _ in range(400):
        optimizer.zero_grad()
        disagreement_loss(ensemble, features, actions, targets).backward()
        optimizer.step()
    with torch.no_grad():
        seen = ensemble(features, actions).mean()
        unseen = ensemble(torch.rand(256, 4) * 0.5 + 3.0, actions).mean()
    assert unseen > 20 * seen


def test_one_step_batch_pairs_each_state_and_action_with_the_next_embedding():
    model = tiny_rssm(n_actions=3)
    model.encoder = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(3 * 64 * 64, 6))
    model.embedding_size = 6
    model.posterior_net[0] = torch.nn.Linear(8 + 6, 8)
    g = torch.Generator().manual_seed(0)
    observations = torch.randint(0, 32, (2, 5, 64, 64, 3), generator=g, dtype=torch.uint8) * 8
    actions = torch.randint(0, 3, (2, 5), generator=g)
    rng_before = torch.random.get_rng_state()
    features, taken, targets = one_step_batch(model, observations, actions, bits=5, seed=4)
    assert torch.equal(torch.random.get_rng_state(), rng_before)  # no global draws
    assert features.shape == (2, 4, 11) and taken.shape == (2, 4, 3) and targets.shape == (2, 4, 6)
    assert torch.equal(taken.argmax(-1), actions[:, :-1])
    from wmthesis.envs.preprocessing import to_float
    with torch.no_grad():
        assert torch.allclose(targets, model.encode(to_float(observations, 5))[:, 1:])
    again = one_step_batch(model, observations, actions, bits=5, seed=4)
    assert torch.equal(again[0], features)  # the same seed, the same filter


def test_training_with_exploration_leaves_the_rssm_updates_alone_and_resumes(tmp_path):
    explore = {"explore_scale": 1.0, "explore_heads": 3}
    pretrain = {"env_steps": 0, "pretrain_updates": 4}
    train_planet("boxing", SMOKE, tmp_path / "thesis", seed=1, progress=False, variant=pretrain)
    train_planet("boxing", SMOKE, tmp_path / "explore", seed=1, progress=False, variant={**pretrain, **explore})
    thesis, _, _ = load_planet(tmp_path / "thesis")
    explored, config, meta = load_planet(tmp_path / "explore")
    assert config.explore_scale == 1.0
    assert all(torch.equal(a, b) for a, b in zip(thesis.state_dict().values(), explored.state_dict().values()))
    assert all(math.isfinite(e["disagreement"]) for e in meta["curve"]["pretrain"])
    assert "disagreement" not in load_planet(tmp_path / "thesis")[2]["curve"]["pretrain"][0]
    assert "explorer" not in torch.load(tmp_path / "thesis" / "checkpoint.pt", weights_only=False)

    straight = train_planet("boxing", SMOKE, tmp_path / "straight", seed=3, progress=False, variant=explore)
    train_planet("boxing", SMOKE, tmp_path / "resumed", seed=3, progress=False, variant={**explore, "env_steps": 48})
    resumed = train_planet("boxing", SMOKE, tmp_path / "resumed", seed=3, progress=False, variant=explore)
    assert resumed["updates"] == straight["updates"] == 6
    a = torch.load(tmp_path / "straight" / "checkpoint.pt", weights_only=False)
    b = torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=False)
    assert all(torch.equal(a["explorer"][k], b["explorer"][k]) for k in a["explorer"])
    assert all(torch.equal(a["model"][k], b["model"][k]) for k in a["model"])
    assert [e["return"] for e in a["curve"]["train"]] == [e["return"] for e in b["curve"]["train"]]
    with pytest.raises(ValueError, match="explore_scale"):
        train_planet("boxing", SMOKE, tmp_path / "straight", seed=3, progress=False)


def test_bonus_by_action_tells_apart_actions_the_ensemble_disagrees_on():
    from wmthesis.planet.explore import bonus_by_action

    model = tiny_rssm(n_actions=3)
    model.encoder = torch.nn.Sequential(torch.nn.Flatten(), torch.nn.Linear(3 * 8 * 8, 6))
    model.embedding_size = 6
    model.posterior_net[0] = torch.nn.Linear(8 + 6, 8)
    ensemble = Disagreement(11, 3, embedding=6, hidden=4, heads=3)
    with torch.no_grad():  # heads that agree on everything but the last action's input weights
        for head in ensemble.heads:
            head.load_state_dict(ensemble.heads[0].state_dict())
        for k, head in enumerate(ensemble.heads):
            head[0].weight[:, -1] += 2.0 * k
    rng = np.random.default_rng(0)
    observations = rng.integers(0, 32, (20, 8, 8, 3), dtype=np.uint8) * 8
    actions = rng.integers(0, 3, 20)
    with torch.no_grad():
        sums = bonus_by_action(model, ensemble, observations, actions, horizon=4, every=5)
    assert sums.shape == (4, 3)
    assert torch.allclose(sums[:, :2], torch.zeros(4, 2), atol=1e-10) and (sums[:, 2] > 0).all()


def test_load_explorer_names_a_missing_run_and_a_run_without_exploration(tmp_path):
    from wmthesis.planet.explore import load_explorer

    model = tiny_rssm(n_actions=3)
    with pytest.raises(FileNotFoundError, match="no PlaNet checkpoint here"):
        load_explorer(tmp_path / "nowhere", model)
    torch.save({"config": {"hidden_size": 4, "explore_heads": 2}}, tmp_path / "checkpoint.pt")
    with pytest.raises(ValueError, match="without exploration"):
        load_explorer(tmp_path, model)
