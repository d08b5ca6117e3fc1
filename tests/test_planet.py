"""PlaNet: the RSSM's loss against torch.distributions, the discrete CEM planner, learning a
moving dot, and the training loop end to end (smoke profile) with resuming."""
import math

import matplotlib
import numpy as np
import pytest
import torch
import torch.distributions as D
from torch import nn

matplotlib.use("Agg")

from wmthesis.planet.config import PlaNetConfig
from wmthesis.config import for_profile  # noqa: E402
from wmthesis.core import Transition  # noqa: E402
from wmthesis.data import EpisodeStore  # noqa: E402
from wmthesis.envs.preprocessing import quantize, to_float  # noqa: E402
from wmthesis.planet import train as planet_module  # noqa: E402
from wmthesis.planet.cem import cem_belief, cem_plan  # noqa: E402
from wmthesis.planet.figures import horizon_error_figure, learning_curve_figure, open_loop_figure
from wmthesis.planet.prediction import evaluate_open_loop, open_loop
from wmthesis.planet.rssm import RSSM, bottle, frames_out, one_hot_previous, planet_loss
from wmthesis.planet.agent import PlanetMind
from wmthesis.planet.train import load_planet, planet_frame, train_planet

SMOKE = for_profile(PlaNetConfig, "smoke")


pytestmark = pytest.mark.usefixtures("one_torch_thread")  # see conftest.py


def tiny_rssm(n_actions=3, seed=0, **sizes) -> RSSM:
    torch.manual_seed(seed)
    sizes = {"belief_size": 8, "state_size": 3, "hidden_size": 8, "reward_hidden_size": 8, **sizes}
    return RSSM(n_actions, **sizes)


def random_batch(batch=2, time=5, n_actions=3, seed=0):
    g = torch.Generator().manual_seed(seed)
    observations = torch.randint(0, 32, (batch, time, 64, 64, 3), generator=g, dtype=torch.uint8) * 8
    actions = torch.randint(0, n_actions, (batch, time), generator=g)
    rewards = torch.randn(batch, time, generator=g)
    return observations, actions, rewards


# ---------------------------------------------------------------------------- loss
def test_loss_matches_a_hand_computation_with_torch_distributions():
    model = tiny_rssm()
    observations, actions, rewards = random_batch()
    rewards = torch.where(rewards.abs() < 0.6, 0.0, rewards)  # some rewarded steps, weighing 3, among plain ones
    assert (rewards[:, :-1] == 0).any() and (rewards[:, :-1] != 0).any()
    B, T, S, distance = 2, 5, 3, 4
    knobs = dict(kl_scale=0.5, free_nats=0.28, decoder_variance=0.3, reward_scale=2.0, reward_event_weight=3.0,
                 overshooting_distance=distance, overshooting_scale=0.25, overshooting_reward_scale=0.7)
    terms = planet_loss(model, observations, actions, rewards, generator=torch.Generator().manual_seed(7),
                        **knobs)

    # The same random draws, in the documented order: dequantisation, posterior samples, overshooting.
    g = torch.Generator().manual_seed(7)
    frames = to_float(observations, 5, noise=g)
    prev = one_hot_previous(actions, 3)
    traj = model.observe(model.encode(frames), prev, g)
    noise = torch.randn((distance - 1, B, T, S), generator=g)

    decoded = D.Normal(model.decode(traj.beliefs, traj.states), math.sqrt(0.3))
    obs_nll = -decoded.log_prob(frames).sum((2, 3, 4)).mean()
    def weighted_mean(nlls, targets):
        weights = [3.0 if r != 0 else 1.0 for r in targets]
        return sum(w * n for w, n in zip(weights, nlls)) / sum(weights)

    predicted = D.Normal(model.reward(traj.beliefs[:, 1:], traj.states[:, 1:]), 1.0)
    reward_nll = weighted_mean(-predicted.log_prob(rewards[:, :-1]).flatten(), rewards[:, :-1].flatten())
    kl = D.kl_divergence(D.Normal(*traj.posterior), D.Normal(*traj.prior)).sum(-1)
    assert (kl < 0.28).any() and (kl > 0.28).any(), "free nats should clip some KL terms and not others"
    kl_loss = torch.clamp(kl, min=0.28).mean()

    per_distance = {d: [] for d in range(2, distance + 1)}
    reward_per_distance = {d: [] for d in range(2, distance + 1)}
    for b in range(B):
        for i in range(T):  # open loop from the one-step prior at i, one row at a time
            belief = traj.beliefs[b:b + 1, i]
            state = traj.prior.mean[b:b + 1, i] + traj.prior.std[b:b + 1, i] * noise[0, b, i]
            for d in range(2, distance + 1):
                t = i + d - 1
                if t >= T:
                    break
                belief, prior = model.transition(belief, state, prev[b:b + 1, t])
                q = D.Normal(traj.posterior.mean[b, t], traj.posterior.std[b, t])
                kl_d = D.kl_divergence(q, D.Normal(prior.mean[0], prior.std[0])).sum()
                per_distance[d].append(torch.clamp(kl_d, min=0.28))
                predicted_d = D.Normal(model.reward(belief, prior.mean)[0], 1.0)
                reward_per_distance[d].append((-predicted_d.log_prob(rewards[b, t - 1]), rewards[b, t - 1]))  # r_t
                if d < distance:
                    state = prior.mean + prior.std * noise[d - 1, b, i]
    overshooting = torch.stack([torch.stack(v).mean() for v in per_distance.values()]).mean()
    overshooting_reward = torch.stack([weighted_mean(*zip(*v)) for v in reward_per_distance.values()]).mean()

    for name, expected in [("observation", obs_nll), ("reward", reward_nll), ("kl", kl.mean()),
                           ("kl_loss", kl_loss), ("overshooting", overshooting),
                           ("overshooting_reward", overshooting_reward)]:
        assert torch.allclose(terms[name], expected, rtol=1e-5, atol=1e-5), name
    total = obs_nll + 2.0 * (reward_nll + 0.7 * overshooting_reward) + 0.5 * (kl_loss + 0.25 * overshooting)
    assert torch.allclose(terms["loss"], total, rtol=1e-6)
    assert overshooting > 0 and len(per_distance[distance]) == B * (T - distance + 1)


def test_prior_reward_and_event_weight_match_a_hand_computation():
    """The reward head scored on the one-step prior means too, rewarded steps weighing 4."""
    model = tiny_rssm()
    observations, actions, _ = random_batch()
    rewards = torch.tensor([[0.0, 1.0, 0.0, -2.0, 5.0], [0.0, 0.0, 0.0, 1.0, 0.0]])  # the last row is never scored
    knobs = dict(free_nats=0.0, reward_scale=3.0, overshooting_distance=0)
    terms = planet_loss(model, observations, actions, rewards, prior_reward_scale=0.5, reward_event_weight=4.0,
                        generator=torch.Generator().manual_seed(5), **knobs)

    g = torch.Generator().manual_seed(5)
    traj = model.observe(model.encode(to_float(observations, 5, noise=g)), one_hot_previous(actions, 3), g)
    weights = {(b, t): 4.0 if rewards[b, t - 1] != 0 else 1.0 for b in range(2) for t in range(1, 5)}

    def weighted_nll(states):
        nll = {k: -D.Normal(model.reward(traj.beliefs[k[0], k[1]], states[k[0], k[1]]), 1.0).log_prob(rewards[k[0], k[1] - 1])
               for k in weights}
        return sum(weights[k] * nll[k] for k in weights) / sum(weights.values())

    assert sum(weights.values()) == 8 + 3 * 3  # three rewarded steps among the scored ones
    assert torch.allclose(terms["reward"], weighted_nll(traj.states), rtol=1e-5)
    assert torch.allclose(terms["prior_reward"], weighted_nll(traj.prior.mean), rtol=1e-5)
    plain = planet_loss(model, observations, actions, rewards, generator=torch.Generator().manual_seed(5), **knobs)
    assert plain["prior_reward"] == 0 and not torch.allclose(plain["reward"], terms["reward"])
    extra = 3.0 * (terms["reward"] + 0.5 * terms["prior_reward"]) - 3.0 * plain["reward"]
    assert torch.allclose(terms["loss"] - plain["loss"], extra, rtol=1e-4, atol=1e-5)
    for bad in (dict(reward_event_weight=0.0), dict(prior_reward_scale=-1.0)):  # a weight sum of 0: NaN
        with pytest.raises(ValueError, match=next(iter(bad))):
            planet_loss(model, observations, actions, rewards, **bad, **knobs)


def test_lowering_the_decoder_variance_is_lowering_the_kl_scale():
    """sigma^2 * L(variance sigma^2, KL scale b, reward scale r) has the gradients of
    L(variance 1, KL scale sigma^2 b, reward scale sigma^2 r) (rssm module docstring)."""
    batch, sigma2 = random_batch(seed=1), 0.05

    def grads(scale, **knobs):
        model = tiny_rssm(seed=3)
        loss = scale * planet_loss(model, *batch, free_nats=0.0, overshooting_distance=3,
                                   generator=torch.Generator().manual_seed(0), **knobs)["loss"]
        loss.backward()
        return torch.cat([p.grad.flatten() for p in model.parameters()])

    low_variance = grads(sigma2, decoder_variance=sigma2, kl_scale=1.0, reward_scale=10.0)
    low_kl = grads(1.0, decoder_variance=1.0, kl_scale=sigma2, reward_scale=10.0 * sigma2)
    assert torch.allclose(low_variance, low_kl, rtol=1e-4, atol=1e-6)
    plain = grads(1.0, decoder_variance=1.0, kl_scale=1.0, reward_scale=10.0)
    assert not torch.allclose(plain, low_kl, rtol=1e-2)


def test_bottle_folds_time_into_batch_for_tensors_and_named_tuples():
    model = tiny_rssm()
    belief, state = torch.randn(2, 4, 8), torch.randn(2, 4, 3)
    action = torch.eye(3)[torch.tensor([[0, 1, 2, 0]] * 2)]
    folded_belief, prior = bottle(model.transition, belief, state, action)
    assert folded_belief.shape == (2, 4, 8) and prior.mean.shape == prior.std.shape == (2, 4, 3)
    direct_belief, direct_prior = model.transition(belief[1], state[1], action[1])
    assert torch.allclose(folded_belief[1], direct_belief) and torch.allclose(prior.std[1], direct_prior.std)
    assert (prior.std >= 0.1).all()


def test_five_bit_frames_round_trip_through_model_floats():
    frames = quantize(np.random.default_rng(0).integers(0, 256, (2, 64, 64, 3), dtype=np.uint8), 5)
    assert torch.equal(frames_out(to_float(frames, 5), 5), torch.from_numpy(frames))
    # Predictions outside [-0.5, 0.5) are clipped to the extreme 5-bit values.
    assert frames_out(torch.tensor([-3.0, 0.49, 7.0]), 5).tolist() == [0, 248, 248]
    sprite = np.random.default_rng(1).integers(0, 256, (63, 63, 3), dtype=np.uint8)  # Sokoban-small, tile 9
    frame = planet_frame(sprite)
    assert frame.shape == (64, 64, 3) and (frame % 8 == 0).all()


# ---------------------------------------------------------------------------- planner
def test_cem_finds_the_unique_best_sequence_of_a_separable_landscape():
    H, A = 6, 5
    scores = torch.randn(H, A, generator=torch.Generator().manual_seed(0))
    calls = []

    def rollout(actions):
        calls.append(actions.shape)
        assert ((actions == 0) | (actions == 1)).all() and (actions.sum(-1) == 1).all()
        return (actions * scores).sum((1, 2))

    g = torch.Generator().manual_seed(0)
    belief = cem_belief(rollout, A, horizon=H, candidates=300, top_k=30, iterations=6, generator=g)
    assert torch.equal(belief.mean.argmax(-1), scores.argmax(-1))
    assert calls == [(300, H, A)] * 6  # one batched evaluation per iteration, nothing per candidate
    assert cem_plan(rollout, A, H, 300, 30, 6, torch.Generator().manual_seed(1)) == int(scores[0].argmax())


def test_cem_first_action_looks_beyond_the_immediate_reward():
    """Action 0 pays 1 now; action 1 pays nothing now but 3 if action 3 follows two steps later."""

    def rollout(actions):
        first = actions[:, 0].argmax(-1)
        third = actions[:, 2].argmax(-1) if actions.shape[1] > 2 else torch.full_like(first, -1)
        return (first == 0).float() + 3.0 * ((first == 1) & (third == 3)).float()

    g = torch.Generator().manual_seed(0)
    assert cem_plan(rollout, 4, horizon=4, candidates=200, top_k=20, iterations=4, generator=g) == 1
    myopic = cem_plan(rollout, 4, horizon=1, candidates=200, top_k=20, iterations=4, generator=g)
    assert myopic == 0  # within a horizon of one step the delayed reward is invisible


def test_cem_rejects_bad_sizes():
    with pytest.raises(ValueError, match="top_k"):
        cem_plan(lambda a: a.sum((1, 2)), 3, 4, candidates=10, top_k=11, iterations=1)


def test_imagined_returns_batch_all_candidates_and_mind_keeps_its_belief():
    model = tiny_rssm(n_actions=4)
    actions = torch.nn.functional.one_hot(torch.randint(0, 4, (50, 7)), 4).float()
    belief, state = model.initial(1)
    with torch.no_grad():
        returns = model.imagined_returns(belief, state, actions, torch.Generator().manual_seed(0))
        beliefs, states = model.imagine(belief.expand(50, -1), state.expand(50, -1), actions, sample=False)
    assert returns.shape == (50,) and beliefs.shape == (50, 7, 8) and states.shape == (50, 7, 3)
    mind = PlanetMind(model, horizon=3, candidates=20, top_k=5, iterations=2)
    frame = np.zeros((64, 64, 3), np.uint8)
    scores = mind.plan(frame)
    assert scores.shape == (4,) and np.isfinite(scores).all()
    first = mind.belief.clone()
    mind.on_step_taken(0, Transition(frame, 2, 0.0, frame, False), {})
    mind.plan(frame)
    assert not torch.equal(mind.belief, first) and mind.prev_action.argmax().item() == 2
    mind.on_episode_start(1, True)
    assert not mind.belief.any() and not mind.prev_action.any()


# ---------------------------------------------------------------------------- learning
DOT, TRACK, SIZE = 3, 8, 16


def dot_video(batch, length, rng):
    """(B, T, 16, 16, 3) uint8 5-bit frames of a 3x3 dot on a ring of 8 positions that action
    1 moves right and action 0 left, and the actions (B, T)."""
    actions = rng.integers(0, 2, (batch, length))
    position = rng.integers(0, TRACK, batch)
    frames = np.zeros((batch, length, SIZE, SIZE, 3), np.uint8)
    for t in range(length):
        for b in range(batch):
            frames[b, t, 6:6 + DOT, 1 + position[b]:1 + DOT + position[b]] = 248
        position = (position + 2 * actions[:, t] - 1) % TRACK
    return torch.from_numpy(frames), torch.from_numpy(actions)


def test_rssm_learns_a_moving_dot_to_a_low_open_loop_error():
    cfg = SMOKE
    torch.manual_seed(0)
    features = cfg.belief_size + cfg.state_size
    encoder = nn.Sequential(nn.Conv2d(3, 16, 4, 2), nn.ReLU(), nn.Conv2d(16, 32, 4, 2), nn.ReLU(), nn.Flatten())
    decoder = nn.Sequential(nn.Linear(features, 128), nn.ReLU(), nn.Linear(128, 3 * SIZE * SIZE),
                            nn.Unflatten(1, (3, SIZE, SIZE)))
    model = RSSM(2, cfg.belief_size, cfg.state_size, cfg.hidden_size, cfg.reward_hidden_size,
                 encoder=encoder, decoder=decoder, embedding_size=128)
    optimizer = torch.optim.Adam(model.parameters(), lr=3e-3, eps=cfg.adam_eps)
    rng, g = np.random.default_rng(0), torch.Generator().manual_seed(0)
    for _ in range(500):
        observations, actions = dot_video(16, 10, rng)
        loss = planet_loss(model, observations, actions, torch.zeros(16, 10), kl_scale=1.0, free_nats=0.0,
                           decoder_variance=0.2, generator=g)["loss"]
        optimizer.zero_grad()
        loss.backward()
        optimizer.step()
    observations, actions = dot_video(32, 12, np.random.default_rng(1))
    result = open_loop(model, observations, actions, context=4, generator=torch.Generator().manual_seed(0))
    blank = (to_float(observations[:, 4:], 5) + 0.5).pow(2).mean().item()  # MSE of predicting the background
    assert result["mse"].shape == (8,) and result["prediction"].shape == observations.shape
    assert result["mse"].mean() < 0.1 * blank and result["mse"][-1] < 0.2 * blank, (result["mse"], blank)
    # The dot is where it should be 8 steps ahead: its centre of brightness along the track.
    centre = lambda rows: (rows * np.arange(SIZE)).sum(-1) / rows.sum(-1)  # noqa: E731
    predicted, true = result["prediction"][:, -1, 7, :, 0], observations[:, -1, 7, :, 0].numpy()
    error = np.abs(centre(predicted / 248.0) - centre(true / 248.0))
    assert np.mean(error < 0.5) > 0.9, error


# ---------------------------------------------------------------------------- training loop
def smoke_state(run_dir):
    model, config, meta = load_planet(run_dir)
    curve = {part: [{k: v for k, v in entry.items() if k != "seconds"} for entry in entries]
             for part, entries in meta["curve"].items()}
    return model.state_dict(), curve, meta["updates"]


def test_training_runs_end_to_end_and_resumes_to_the_same_state(tmp_path):
    straight = train_planet("boxing", SMOKE, tmp_path / "straight", seed=3, progress=False)
    assert straight["episodes"] == 5 and straight["env_steps"] == 80 and straight["updates"] == 6
    assert len(straight["curve"]["train"]) == 3 and len(straight["curve"]["test"]) == 3
    assert all(math.isfinite(entry["loss"]) for entry in straight["curve"]["train"])
    assert (tmp_path / "straight" / "curve.json").exists()

    half = train_planet("boxing", SMOKE, tmp_path / "resumed", seed=3, progress=False,
                        variant={"env_steps": 48})
    assert half["episodes"] == 3 and half["updates"] == 2
    saved = torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=False)
    for field in ("prior_reward_scale", "reward_event_weight"):  # a run saved before these fields existed
        del saved["config"][field]
    torch.save(saved, tmp_path / "resumed" / "checkpoint.pt")
    resumed = train_planet("boxing", SMOKE, tmp_path / "resumed", seed=3, progress=False)
    assert resumed["updates"] == 6
    params_a, curve_a, _ = smoke_state(tmp_path / "straight")
    params_b, curve_b, _ = smoke_state(tmp_path / "resumed")
    assert curve_a == curve_b
    assert all(torch.equal(params_a[name], params_b[name]) for name in params_a)
    with EpisodeStore(tmp_path / "straight" / "episodes.h5") as a, \
            EpisodeStore(tmp_path / "resumed" / "episodes.h5") as b:
        assert np.array_equal(a.episode(-1)["observations"], b.episode(-1)["observations"])
        assert (a.episode(0)["observations"] % 8 == 0).all()

    again = train_planet("boxing", SMOKE, tmp_path / "straight", seed=3, progress=False)  # finished: no work
    assert again["updates"] == 6 and again["curve"] == straight["curve"]
    with pytest.raises(ValueError, match="kl_scale"):
        train_planet("boxing", SMOKE, tmp_path / "straight", seed=3, progress=False, variant="free-nats")


def test_a_nan_loss_stops_naming_the_update_and_keeps_the_checkpoint(tmp_path, monkeypatch):
    train_planet("boxing", SMOKE, tmp_path, seed=0, progress=False, variant={"env_steps": 48})
    before = (tmp_path / "checkpoint.pt").read_bytes()
    real = planet_module.planet_loss

    def poisoned(*args, **kwargs):
        terms = real(*args, **kwargs)
        return {**terms, "loss": terms["loss"] * float("nan")}

    monkeypatch.setattr(planet_module, "planet_loss", poisoned)
    with pytest.raises(FloatingPointError, match=r"at update 3 .*checkpoint \(update 2\) is kept"):
        train_planet("boxing", SMOKE, tmp_path, seed=0, progress=False)
    assert (tmp_path / "checkpoint.pt").read_bytes() == before


def test_open_loop_evaluation_and_figures_on_a_smoke_run(tmp_path):
    train_planet("sokoban-small", SMOKE, tmp_path, seed=0, progress=False, variant={"env_steps": 48})
    model, config, meta = load_planet(tmp_path)
    with EpisodeStore(tmp_path / "episodes.h5") as store:
        result = evaluate_open_loop(model, store, sequences=3, length=12, context=5)
    assert result["truth"].shape == result["prediction"].shape == (3, 12, 64, 64, 3)
    assert result["mse"].shape == (7,) and np.isfinite(result["mse"]).all()
    assert (result["prediction"] % 8 == 0).all()
    figure = open_loop_figure(result, sequences=2)
    assert len(figure.axes) == 2 * 2 * 12
    horizon_error_figure({"smoke": result["mse"]})
    learning_curve_figure({"smoke": meta["curve"]}, references={"random": 0.0})


def test_the_studys_contrast_and_the_budget_beside_the_thesiss_best_boxing_setting():
    from wmthesis.planet.bouts import budget_table
    from wmthesis.planet.config import PlaNetConfig
    from wmthesis.planet.study import study_contrast

    entry = lambda first, last: {"model": {"1": {"mean": first}, "15": {"mean": last}}}  # noqa: E731
    summary = {"unchanged": entry(0.03, 0.05), "free-nats": entry(0.02, 0.07)}
    assert study_contrast({"summary": summary}) == ("lowest error at +1: free-nats's (0.0200); at +15: unchanged's "
                                                   "(0.0500) (of unchanged, free-nats)")
    tuned = PlaNetConfig(kl_scale=0.03, free_nats=12.0, overshooting_distance=0, frame_size=32)
    table = budget_table(tuned, {"updates": 10, "env_steps": 20})
    assert "| latent overshooting distance | 0 | 50 | 0 |" in table
    assert "| frames | 32x32, 5 bits | 64x64, 5 bits | 64x64, 5 bits |" in table
    assert "| batch (chunks x steps) | 50 x 50 | 50 x 50 | 50 x 50 |" in table  # PlaNet's public batch
    # KL scale and free nats are 5.6.3-5.6.4's; the thesis keeps latent overshooting (4.4.5)
    assert "differs from the thesis's best Boxing setting: frame_size, overshooting_distance. PlaNet's public" in table
