"""PlaNet's model study (thesis 5.6.1-5.6.4): frames of any size, the moving-pixel error and
its baselines, the latent diagnostics, training on seed episodes alone and an agent that goes on
from such a run."""
import dataclasses

import matplotlib
import numpy as np
import pytest
import torch
import torch.distributions as D

matplotlib.use("Agg")

from wmthesis.planet.config import PlaNetConfig
from wmthesis.config import for_profile  # noqa: E402
from wmthesis.data import EpisodeStore  # noqa: E402
from wmthesis.envs.atari import make_atari  # noqa: E402
from wmthesis.planet.networks import vision_networks  # noqa: E402
from wmthesis.planet.prediction import (background_frame, baseline_predictions, latent_diagnostics,  # noqa: E402
                                        moving_error, moving_open_loop)
from wmthesis.planet.rssm import RSSM  # noqa: E402
from wmthesis.planet.study import summarise  # noqa: E402
from wmthesis.planet.train import load_planet, make_planet_env, planet_frame, train_planet  # noqa: E402

SMOKE = for_profile(PlaNetConfig, "smoke")
pytestmark = pytest.mark.usefixtures("one_torch_thread")


# ---------------------------------------------------------------------------- frames and networks
@pytest.mark.parametrize("size, depth, embedding", [(32, 16, 512), (16, 4, 64), (64, 32, 1024)])
def test_vision_networks_map_frames_to_embeddings_and_back(size, depth, embedding):
    encoder, decoder, width = vision_networks(size, depth, features=20)
    assert width == embedding
    assert encoder(torch.zeros(2, 3, size, size)).shape == (2, embedding)
    assert decoder(torch.zeros(2, 20)).shape == (2, 3, size, size)


def test_the_thesis_size_keeps_planets_own_networks_and_bad_sizes_fail():
    from wmthesis.world_models.vision import Encoder

    assert isinstance(vision_networks(64, 32, 230)[0], Encoder)
    for size, depth in ((48, 16), (2, 16), (32, 0)):
        with pytest.raises(ValueError, match="power of two"):
            vision_networks(size, depth, 230)


def test_cropped_frames_show_the_ring_at_the_configured_size():
    config = dataclasses.replace(SMOKE, frame_size=32, crop=True)
    env = make_planet_env("boxing", config)
    frame, _ = env.reset(seed=0)
    env.close()
    raw, _ = make_atari("Boxing").reset(seed=0)
    assert frame.shape == (32, 32, 3) and (frame % 8 == 0).all()
    assert np.array_equal(frame, planet_frame(raw, 5, 32, (30, 183, 28, 131)))
    assert not np.array_equal(frame, planet_frame(raw, 5, 32))      # the whole screen differs


# ---------------------------------------------------------------------------- moving pixels
def scene_with_a_block(position, size=8, value=255):
    frame = np.zeros((size, size, 3), np.uint8)
    frame[position:position + 2, 2:4] = value
    return frame


def test_background_is_what_stays_put():
    frames = np.stack([scene_with_a_block(p) for p in (0, 2, 4, 6)])  # the block never twice in a place
    assert (background_frame(frames) == 0).all()


def test_moving_error_counts_the_moving_pixels_of_truth_and_prediction():
    background = np.zeros((8, 8, 3), np.uint8)
    truth = scene_with_a_block(2)[None, None]                          # (1, 1, 8, 8, 3)
    assert moving_error(truth, truth, background)[0] == 0.0
    # Only the background: every moving pixel of the truth is wrong by the full range.
    assert moving_error(truth, background[None, None], background)[0] == pytest.approx(1.0)
    # The block in the wrong place pays at both places (8 pixels, all wrong).
    assert moving_error(truth, scene_with_a_block(5)[None, None], background)[0] == pytest.approx(1.0)
    # Half right: moved by one row, 2 of the 6 pixels it or the truth covers are right.
    assert moving_error(truth, scene_with_a_block(3)[None, None], background)[0] == pytest.approx(4 / 6)
    # A faint blur below the tolerance is background and costs only on the truth's pixels.
    faint = np.full((1, 1, 8, 8, 3), 16, np.uint8)
    expected = ((255 - 16) / 255) ** 2
    assert moving_error(truth, faint, background)[0] == pytest.approx(expected)


def test_baselines_repeat_the_last_context_frame_and_the_mean_frame():
    truth = np.stack([scene_with_a_block(p) for p in range(5)])[None]     # (1, 5, 8, 8, 3)
    mean = np.full((8, 8, 3), 7, np.uint8)
    baselines = baseline_predictions(truth, context=2, mean_frame=mean)
    assert baselines["repeat last"].shape == (1, 3, 8, 8, 3)
    assert all(np.array_equal(frame, truth[0, 1]) for frame in baselines["repeat last"][0])
    assert (baselines["mean frame"] == 7).all()


def test_filtered_error_scores_the_context_reconstructions_and_the_mean_frame_on_the_context():
    torch.manual_seed(0)
    encoder, decoder, embedding = vision_networks(16, 4, 8 + 3)
    model = RSSM(3, 8, 3, 8, 8, encoder=encoder, decoder=decoder, embedding_size=embedding).eval()
    observations = torch.randint(0, 32, (2, 6, 16, 16, 3), dtype=torch.uint8) * 8
    background, mean = np.zeros((16, 16, 3), np.uint8), np.full((16, 16, 3), 40, np.uint8)
    result = moving_open_loop(model, observations, torch.randint(0, 3, (2, 6)), background=background,
                              mean_frame=mean, context=4, seed=1)
    truth, prediction = result["rollout"]["truth"], result["rollout"]["prediction"]
    assert len(result["filtered"]["model"]) == 4 and len(result["model"]) == 2  # the context, then the horizon
    np.testing.assert_allclose(result["filtered"]["model"], moving_error(truth[:, :4], prediction[:, :4], background))
    np.testing.assert_allclose(result["filtered"]["mean frame"],
                               moving_error(truth[:, :4], np.broadcast_to(mean, truth[:, :4].shape), background))
    np.testing.assert_allclose(result["mean frame"], moving_error(truth[:, 4:], np.broadcast_to(mean, truth[:, 4:].shape),
                                                                  background))


def test_latent_diagnostics_entropies_match_torch_distributions():
    torch.manual_seed(0)
    encoder, decoder, embedding = vision_networks(16, 4, 8 + 3)
    model = RSSM(3, 8, 3, 8, 8, encoder=encoder, decoder=decoder, embedding_size=embedding).eval()
    observations = torch.randint(0, 32, (2, 4, 16, 16, 3), dtype=torch.uint8) * 8
    actions = torch.randint(0, 3, (2, 4))
    result = latent_diagnostics(model, observations, actions, seed=1)
    from wmthesis.envs.preprocessing import to_float
    from wmthesis.planet.rssm import one_hot_previous

    frames = to_float(observations, 5) + 0.5 / 32
    with torch.no_grad():
        trajectory = model.observe(model.encode(frames), one_hot_previous(actions, 3), torch.Generator().manual_seed(1))
    q = D.Normal(trajectory.posterior.mean, trajectory.posterior.std)
    p = D.Normal(trajectory.prior.mean, trajectory.prior.std)
    assert result["posterior_entropy"] == pytest.approx(float(q.entropy().sum(-1).mean()), rel=1e-5)
    assert result["prior_entropy"] == pytest.approx(float(p.entropy().sum(-1).mean()), rel=1e-5)
    assert result["kl"] == pytest.approx(float(D.kl_divergence(q, p).sum(-1).mean()), rel=1e-5)
    embedded = model.encode(frames).detach().reshape(8, -1).numpy()
    assert result["embedding_spread"] == pytest.approx(float(embedded.std(0, ddof=1).mean()), rel=1e-5)


def test_embedding_spread_is_zero_for_an_encoder_blind_to_its_frames():
    torch.manual_seed(0)
    encoder, decoder, embedding = vision_networks(16, 4, 8 + 3)
    model = RSSM(3, 8, 3, 8, 8, encoder=encoder, decoder=decoder, embedding_size=embedding).eval()
    observations = torch.randint(0, 32, (2, 4, 16, 16, 3), dtype=torch.uint8) * 8
    seeing = latent_diagnostics(model, observations, torch.zeros(2, 4, dtype=torch.long))["embedding_spread"]
    with torch.no_grad():
        model.encoder.net[0].weight.zero_()  # the first layer drops the frame: every frame embeds alike
    blind = latent_diagnostics(model, observations, torch.zeros(2, 4, dtype=torch.long))["embedding_spread"]
    assert seeing > 1e-3 and blind == pytest.approx(0.0, abs=1e-6)


def test_summary_says_whether_every_seed_beats_both_baselines():
    def run(model):
        return {"errors": {"model": model, "repeat last": [0.5] * 5, "mean frame": [0.6] * 5},
                "diagnostics": {"kl": 1.0}}

    summary = summarise({"good": [run([0.1] * 5), run([0.2] * 5)],
                         "one seed worse": [run([0.1] * 5), run([0.1] * 4 + [0.55])]}, horizons=(1, 5))
    assert summary["good"]["beats_baselines"] and not summary["one seed worse"]["beats_baselines"]
    assert summary["good"]["model"][1] == {"mean": pytest.approx(0.15), "min": 0.1, "max": 0.2}
    assert summary["one seed worse"]["model"][5]["max"] == 0.55


# ---------------------------------------------------------------------------- training on seed episodes
def test_the_kl_scale_does_nothing_while_the_kl_stays_under_the_free_nats(tmp_path):
    """The thesis's 5.6.3 knob only acts when KL > free nats: below them the clamped term is a
    constant, so KL scale 1 and 0.03 train to the same weights (the issue's diagnosis)."""
    config = dataclasses.replace(SMOKE, env_steps=0, pretrain_updates=3, free_nats=1e3)
    for kl_scale in (1.0, 0.03):
        train_planet("boxing", dataclasses.replace(config, kl_scale=kl_scale), tmp_path / str(kl_scale),
                     seed=0, progress=False)
    a, b = load_planet(tmp_path / "1.0")[0].state_dict(), load_planet(tmp_path / "0.03")[0].state_dict()
    assert all(torch.equal(a[name], b[name]) for name in a)
    config = dataclasses.replace(config, free_nats=0.0)
    for kl_scale in (1.0, 0.03):
        train_planet("boxing", dataclasses.replace(config, kl_scale=kl_scale), tmp_path / f"open{kl_scale}",
                     seed=0, progress=False)
    a, b = load_planet(tmp_path / "open1.0")[0].state_dict(), load_planet(tmp_path / "open0.03")[0].state_dict()
    assert not all(torch.equal(a[name], b[name]) for name in a)


def test_updates_on_seed_episodes_alone_then_an_agent_goes_on_from_them(tmp_path):
    study = dataclasses.replace(SMOKE, env_steps=0, pretrain_updates=5)
    first = train_planet("boxing", study, tmp_path / "study", seed=1, progress=False)
    assert first["episodes"] == SMOKE.seed_episodes and first["updates"] == 5
    assert [entry["updates"] for entry in first["curve"]["pretrain"]] == [2, 4, 5]   # blocks of update_steps
    assert first["curve"]["train"] == []
    before = load_planet(tmp_path / "study")[0].state_dict()

    agent = train_planet("boxing", dataclasses.replace(study, env_steps=48), tmp_path / "agent", seed=1,
                         progress=False, start_from=tmp_path / "study")
    assert agent["updates"] == 5 + 2 and agent["episodes"] == SMOKE.seed_episodes + 1
    assert load_planet(tmp_path / "study")[0].state_dict().keys() == before.keys()
    assert all(torch.equal(before[k], v) for k, v in load_planet(tmp_path / "study")[0].state_dict().items())
    with EpisodeStore(tmp_path / "study" / "episodes.h5") as a, EpisodeStore(tmp_path / "agent" / "episodes.h5") as b:
        assert len(a) == SMOKE.seed_episodes and len(b) == SMOKE.seed_episodes + 1
        assert np.array_equal(a.episode(0)["observations"], b.episode(0)["observations"])
    with pytest.raises(FileNotFoundError, match="no PlaNet checkpoint to start from"):
        train_planet("boxing", study, tmp_path / "other", seed=1, progress=False, start_from=tmp_path / "none")


def test_a_store_of_another_frame_size_is_refused_naming_both(tmp_path):
    config = dataclasses.replace(SMOKE, env_steps=0, pretrain_updates=2)
    train_planet("boxing", config, tmp_path, seed=0, progress=False)
    (tmp_path / "checkpoint.pt").unlink()
    with pytest.raises(ValueError, match=r"obs_shape=\(64, 64, 3\) but \(32, 32, 3\)"):
        train_planet("boxing", dataclasses.replace(config, frame_size=32), tmp_path, seed=0, progress=False)
