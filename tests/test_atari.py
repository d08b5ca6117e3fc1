"""Atari environments (ale-py) and frame preprocessing."""
import cv2
import numpy as np
import pytest
import torch

from wmthesis.envs import make_env
from wmthesis.envs.atari import make_atari
from wmthesis.envs.preprocessing import CROPS, crop_resize, quantize, to_float, to_uint8

RING = (195, 144, 61)  # Boxing's ring ropes


def play(env, actions, seed=0):
    """Frames seen when playing `actions` after ``reset(seed)``: (len(actions) + 1, ...)."""
    frames = [env.reset(seed=seed)[0]]
    for action in actions:
        frames.append(env.step(action)[0])
    return np.stack(frames)


@pytest.mark.parametrize("name, n_actions", [("boxing", 18), ("freeway", 3)])
def test_action_space_is_the_games_own(name, n_actions):
    assert make_env(name).action_space.n == n_actions


@pytest.mark.parametrize("name", ["boxing", "freeway"])
@pytest.mark.parametrize("preprocessing, shape", [("none", (210, 160, 3)), ("world_models", (64, 64, 3)),
                                                  ("planet", (64, 64, 3))])
def test_observations_match_their_space(name, preprocessing, shape):
    env = make_env(name, preprocessing=preprocessing)
    assert env.observation_space.shape == shape and env.observation_space.dtype == np.uint8
    for frame in play(env, [1, 2, 0]):
        assert frame.shape == shape and frame.dtype == np.uint8
        assert env.observation_space.contains(frame)


@pytest.mark.parametrize("preprocessing", ["none", "world_models"])
def test_same_seed_and_actions_give_the_same_frames(preprocessing):
    actions = np.random.default_rng(0).integers(0, 18, 60)
    first = play(make_env("boxing", preprocessing=preprocessing), actions, seed=3)
    second = play(make_env("boxing", preprocessing=preprocessing), actions, seed=3)
    assert np.array_equal(first, second)
    assert not np.array_equal(first[0], first[-1])  # the game did move


def test_planet_frames_have_5_bits_and_round_trip_exactly():
    frames = play(make_env("boxing", preprocessing="planet"), [1] * 10)
    assert np.all(frames % 8 == 0)
    assert torch.equal(to_uint8(to_float(frames, bits=5), bits=5), torch.from_numpy(frames))
    every = np.arange(256, dtype=np.uint8)
    for bits in (5, 8):
        assert torch.equal(to_uint8(to_float(quantize(every, bits), bits), bits),
                           torch.from_numpy(quantize(every, bits)))


def test_to_float_follows_planet_preprocess():
    values = np.array([0, 7, 8, 255], np.uint8)
    assert torch.allclose(to_float(values, bits=5), torch.tensor([0, 0, 1, 31]) / 32 - 0.5)
    assert torch.allclose(to_float(values, bits=8), torch.tensor([0, 7, 8, 255]) / 256 - 0.5)
    frames = np.arange(256, dtype=np.uint8).repeat(100)
    clean = to_float(frames, bits=5)
    noisy = to_float(frames, bits=5, noise=torch.Generator().manual_seed(0))
    noise = noisy - clean
    assert noise.min() >= 0 and noise.max() <= 1 / 32 and noise.std() > 0.005  # within one bin
    assert noisy.min() >= -0.5 and noisy.max() <= 0.5
    with pytest.raises(TypeError, match="uint8"):
        to_float(np.zeros(3, np.float32))


def test_world_models_frame_is_the_authors_crop_with_the_whole_ring():
    actions = np.random.default_rng(1).integers(0, 18, 30)
    raw = play(make_env("boxing"), actions)
    cropped = play(make_env("boxing", preprocessing="world_models"), actions)
    assert CROPS["Boxing"] == (30, 183, 28, 131)
    for frame, observation in zip(raw, cropped):
        manual = cv2.resize(frame[30:183, 28:131], (64, 64), interpolation=cv2.INTER_AREA)
        assert np.array_equal(observation, manual)
    # the ropes lie on all four borders of the observation: the ring is inside
    for edge in (cropped[:, 0, 32], cropped[:, 63, 32], cropped[:, 32, 0], cropped[:, 32, 63]):
        assert np.all(edge == RING)


def test_freeway_crop_keeps_both_sidewalks_and_drops_the_margin():
    raw = make_env("freeway").reset(seed=0)[0]
    top, bottom, left, right = CROPS["Freeway"]
    kept = raw[top:bottom, left:right]
    assert np.all(raw[:, :left] == 0)                       # the black margin is dropped
    assert np.all(kept[1:9] == 170) and np.all(kept[-9:-1] == 170)  # both grey sidewalks kept
    assert crop_resize(raw, CROPS["Freeway"]).shape == (64, 64, 3)


@pytest.mark.parametrize("name", ["boxing", "freeway"])
def test_action_repeat_8_advances_twice_the_frames_of_4(name):
    advanced = {}
    for repeat in (4, 8):
        env = make_env(name, action_repeat=repeat)
        play(env, [0] * 10)
        advanced[repeat] = env.unwrapped.ale.getEpisodeFrameNumber()
    assert advanced == {4: 40, 8: 80}


def test_max_steps_truncates():
    env = make_env("boxing", preprocessing="world_models", max_steps=5)
    env.reset(seed=0)
    flags = [env.step(0)[2:4] for _ in range(5)]
    assert flags == [(False, False)] * 4 + [(False, True)]


def test_bad_options_fail_listing_the_valid_ones():
    with pytest.raises(ValueError, match="world_models"):
        make_env("boxing", preprocessing="world-models")
    with pytest.raises(ValueError, match="Boxing"):
        make_atari("Pong")
    with pytest.raises(ValueError, match="action_repeat"):
        make_env("boxing", action_repeat=0)
    with pytest.raises(ValueError, match="bits"):
        quantize(np.zeros(3, np.uint8), bits=0)


def test_freeway_lookahead_with_the_emulator_as_its_model_outplays_up_and_leaves_the_game_as_it_was():
    from wmthesis.envs.freeway import CHICKEN_Y, lookahead_action, play_lookahead

    def up_every_step(env, seed=0):
        env.reset(seed=seed)
        return [float(env.step(1)[1]) for _ in range(300)]

    env = make_env("freeway", max_steps=300)
    up = up_every_step(env)
    once = play_lookahead(env, 1, 0)
    assert once["rewards"].tolist() == up and set(once["actions"]) == {1}  # horizon 1: nothing to wait for
    three = play_lookahead(env, 3, 0)
    assert sum(up) == 4 and three["rewards"].sum() == 5  # waiting for a car to pass pays in 300 steps
    assert 0 < (three["actions"] == 0).sum() < 100 and len(three["observations"]) == 300
    assert np.array_equal(three["observations"][0], env.reset(seed=0)[0])  # each frame seen before its action
    env.reset(seed=0)
    for _ in range(40):
        env.step(1)
    ram = env.unwrapped.ale.getRAM().copy()
    assert lookahead_action(env, 6) in (0, 1)
    assert np.array_equal(env.unwrapped.ale.getRAM(), ram)  # every plan was played on a copy
    assert ram[CHICKEN_Y] > 6  # the chicken's height: it left the start after 40 steps up


def test_freeway_lookahead_refuses_other_games_and_bad_horizons():
    from wmthesis.envs.freeway import lookahead_action

    with pytest.raises(ValueError, match="plays Freeway, got 'boxing'"):
        lookahead_action(make_env("boxing"), 3)
    freeway = make_env("freeway")
    freeway.reset(seed=0)
    for horizon in (0, 2.5, True):
        with pytest.raises(ValueError, match="horizon must be a positive integer"):
            lookahead_action(freeway, horizon)
