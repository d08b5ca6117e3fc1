"""`wmthesis.load`: one protocol for every agent family, the shipped decoders, and the refusals
of bad names, missing agents, foreign files and wrong frames."""
from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

import wmthesis
from wmthesis.declarations import AGENTS

REPO = Path(__file__).resolve().parents[1]
SHIPPED = REPO / "data"


@pytest.fixture
def shipped(monkeypatch):
    """The data folder the repository ships (its quick agents)."""
    monkeypatch.setenv("WMTHESIS_DATA", str(SHIPPED))


def committed(experiment: str, *parts: str) -> dict:
    return json.loads((SHIPPED / "results" / experiment / "quick-seed0" / Path(*parts) / "metrics.json").read_text())


def test_bad_names_are_refused_in_one_line_before_torch_loads():
    code = ("import sys, wmthesis\n"
            "for args, kw in [(('nope',), {}), (('boxing-wm',), {'variant': 'x'}), (('boxing-wm',), {'profile': 'big'}),"
            " (('boxing-wm',), {'seed': -1}), (('sokoban-search',), {'variant': 'x'})]:\n"
            "    try:\n        wmthesis.load(*args, **kw)\n    except ValueError as e:\n        print(e)\n"
            "print('torch' in sys.modules)\n")
    lines = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.splitlines()
    assert lines[-1] == "False"  # refused before torch, ale-py or an agent file loaded
    assert "unknown experiment with an agent 'nope'" in lines[0] and all(name in lines[0] for name in AGENTS)
    assert "unknown variant 'x' of boxing-wm" in lines[1] and "separable-64" in lines[1]
    assert "unknown profile 'big'" in lines[2] and "seed must be an integer" in lines[3]
    assert "sokoban-search has no variants" in lines[4]


def test_a_missing_agent_names_the_command_that_trains_it(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    with pytest.raises(FileNotFoundError, match=r"reproduce planet-boxing-agent --profile quick --seed 3`"):
        wmthesis.load("planet-boxing-agent", seed=3)
    assert not any(tmp_path.rglob("*.pt"))  # nothing trained or downloaded


def test_truncated_and_foreign_agent_files_are_one_line_naming_the_file(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    target = wmthesis.agent_file("planet-boxing-agent", seed=0)
    target.parent.mkdir(parents=True)
    target.write_bytes((SHIPPED / "quick/planet-boxing-agent/seed0/agent.pt").read_bytes()[:1000])
    with pytest.raises(ValueError, match=rf"cannot read {target}"):
        wmthesis.load("planet-boxing-agent")
    shutil.copy(SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt", target)  # World Models in PlaNet's place
    with pytest.raises(ValueError, match=rf"{target} is not a wmthesis-planet-agent file"):
        wmthesis.load("planet-boxing-agent")


def test_the_world_models_agent_plays_its_scored_bout_and_a_policy_of_ones_own(shipped):
    agent = wmthesis.load("boxing-wm")
    assert (agent.variant, agent.vision, agent.memory, agent.controller is not None) == \
        ("separable-64", agent.vision, agent.memory, True)
    assert agent.play(bouts=1) == committed("boxing-wm", "separable-64")["returns"][:1]  # +44, as the summary's
    env = agent.env()
    _, info = env.reset(seed=agent.scored_seeds(1)[0])
    played = [env.step(5)[-1]["action"] for _ in range(info["noops"] + 1)]
    assert played == [0] * info["noops"] + [5]  # the scored no-ops, where the memory sees them
    steps = []
    returns = agent.play(bouts=1, policy=lambda frame: steps.append(frame.shape) or 1, max_steps=300)
    assert len(steps) == 300 and steps[0] == (64, 64, 3) and isinstance(returns[0], float)
    with pytest.raises(ValueError, match=r"the policy must return an action in \[0, 18\)"):
        agent.play(bouts=1, policy=lambda frame: 18, max_steps=5)


def test_the_shipped_vision_decodes_real_frames_better_than_their_mean_image(shipped):
    agent = wmthesis.load("boxing-wm")
    env = agent.env()
    frame, _ = env.reset(seed=1)
    frames = [frame]
    for t in range(200):
        frames.append(env.step(t % 18)[0])
    frames = np.stack(frames[25::25])  # 8 real frames, numpy in, numpy out
    reconstructions = agent.vision.reconstruct(frames)
    error = np.abs(reconstructions.astype(float) - frames).mean()
    flat = np.abs(frames.mean(0, keepdims=True) - frames).mean()  # the best constant image
    assert reconstructions.shape == frames.shape and error < 0.5 * flat
    z = agent.vision(frames)
    assert not z.requires_grad and z.shape == (8, 16)
    assert "fitted after the agent" in agent.decoder_info["what"]  # the file says where the decoder came from
    with pytest.raises(ValueError, match=r"uint8 frames \(N, 64, 64, 3\).*agent.env\(\)"):
        agent.vision(frames.astype(np.float32))


def test_without_its_decoder_file_a_vision_refuses_to_decode(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    target = wmthesis.agent_file("boxing-wm")
    target.parent.mkdir(parents=True)
    shutil.copy(SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt", target)
    agent = wmthesis.load("boxing-wm")
    with pytest.raises(RuntimeError, match="no decoder ships for this vision"):
        agent.vision.decode(np.zeros((1, 16), np.float32))


def test_the_alphazero_agent_searches_with_its_runs_settings(shipped):
    from wmthesis.alphazero.evaluation import evaluation_seeds
    from wmthesis.alphazero.replay import game_seeds

    agent = wmthesis.load("boxing-wm-alphazero")
    assert agent.variant == "own-memory" and agent.search.config.simulations == agent.config.simulations
    assert agent.scored_seeds(2) == [game_seeds(s)[0] for s in evaluation_seeds(0, 2, agent.config.noop_max)]
    assert agent.vision.decode(agent.vision(np.zeros((1, 64, 64, 3), np.uint8))).shape == (1, 64, 64, 3)
    mind = agent.mind()
    mind.on_episode_start(0, False)  # as wmthesis.core.loop does, the mind among the callbacks
    scores = mind.plan(np.zeros((64, 64, 3), np.uint8), train_mode=False)
    assert scores.shape == (18,)


def test_planet_agents_see_their_own_frames_and_plan(shipped):
    agent = wmthesis.load("planet-boxing-agent")
    env = agent.env()
    frame, _ = env.reset(seed=agent.scored_seeds(1)[0])
    assert frame.shape == agent.model.encoder_input_shape == (32, 32, 3)
    scores = agent.mind().plan(frame)
    assert scores.shape == (18,)
    with pytest.raises(ValueError, match=r"uint8 frames \(32, 32, 3\), got torch.uint8 \(64, 64, 3\)"):
        agent.mind().plan(np.zeros((64, 64, 3), np.uint8))
    value = wmthesis.load("planet-boxing-value")
    assert value.value is not None and value.planner.horizon >= 1 and value.mind().plan(frame).shape == (18,)


@pytest.mark.skipif(not (SHIPPED / "quick/planet-boxing-agent/seed0/decoder.pt").is_file(),
                    reason="the PlaNet decoder has not been fitted yet")
def test_planet_decodes_open_loop_predictions_better_than_repeating_the_last_frame(shipped):
    agent = wmthesis.load("planet-boxing-agent")
    env = agent.env()
    frame, _ = env.reset(seed=4)
    rng = np.random.default_rng(0)
    frames, actions = [frame], []
    for _ in range(60):
        actions.append(int(rng.integers(18)))
        frames.append(env.step(actions[-1])[0])
    out = agent.open_loop(np.stack(frames[:60]), actions[:60], context=50)
    assert out["prediction"].shape == (60, 32, 32, 3) and len(out["mse"]) == 10
    truth = out["truth"][50:].astype(float)
    prediction_error = np.abs(out["prediction"][50:].astype(float) - truth).mean()
    mean_error = np.abs(truth.mean((0, 1, 2)) - truth).mean()  # a flat frame of the mean colour
    assert prediction_error < mean_error
    assert wmthesis.load("planet-boxing-value").model.decoder is not None  # shares its PlaNet agent's decoder


def test_the_sokoban_agent_solves_a_level_written_by_hand_and_replays_it(shipped):
    agent = wmthesis.load("sokoban-search")
    level = """
##########
#   #    #
# $   .  #
#  ## $  #
# @   .  #
##########"""
    record = agent.solve(level)
    assert record["solved"] and agent.replay(level, record["actions"])["solved"]
    assert not agent.replay(level, record["actions"][:-1])["solved"]  # the last push is what solves it
    from wmthesis.sokoban_search.evaluation import check_solutions

    plays = [agent.search.play(agent.env(), s).record() for s in agent.scored_seeds(2)]
    assert agent.play(bouts=2) == [float(p["solved"]) for p in plays]
    assert all(check_solutions("sokoban", [p for p in plays if p["solved"]]))


def test_a_file_of_another_game_or_variant_is_refused_naming_both(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    freeway = wmthesis.agent_file("planet-freeway")
    freeway.parent.mkdir(parents=True)
    shutil.copy(SHIPPED / "quick/planet-boxing-agent/seed0/agent.pt", freeway)  # Boxing's agent in Freeway's place
    with pytest.raises(ValueError, match=rf"{freeway} holds a boxing agent, not planet-freeway's \(freeway\)"):
        wmthesis.load("planet-freeway")
    own_memory = wmthesis.agent_file("boxing-wm-alphazero")
    own_memory.parent.mkdir(parents=True)
    shutil.copy(SHIPPED / "quick/boxing-wm-alphazero/seed0/agent-imitation.pt", own_memory)
    vision = wmthesis.agent_file("boxing-wm")  # the vision the AlphaZero agents share
    vision.parent.mkdir(parents=True)
    shutil.copy(SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt", vision)
    with pytest.raises(ValueError, match=rf"{own_memory} holds boxing-wm-alphazero's imitation agent, not own-memory"):
        wmthesis.load("boxing-wm-alphazero")
    sokoban = wmthesis.agent_file("sokoban-search")  # a World Models agent in the Sokoban agent's place
    sokoban.parent.mkdir(parents=True)
    shutil.copy(SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt", sokoban)
    with pytest.raises(ValueError, match=rf"{sokoban} holds a \S+ file \(version \d+\), not a Sokoban search run's"):
        wmthesis.load("sokoban-search")


def test_alphazero_agents_can_share_the_vision_of_their_world_models_agent(tmp_path):
    from wmthesis.alphazero.agent import load_agent, share_vision

    wm = tmp_path / "boxing-wm" / "seed0" / "agent-separable-64.pt"
    az = tmp_path / "boxing-wm-alphazero" / "seed0" / "agent-own-memory.pt"
    for source, target in ((SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt", wm),
                           (SHIPPED / "quick/boxing-wm-alphazero/seed0/agent-own-memory.pt", az)):
        target.parent.mkdir(parents=True)
        shutil.copy(source, target)
    saved = torch.load(az, weights_only=False)  # the shipped file names the vision it shares
    assert saved["encoder"] is None and saved["vision_file"]["path"] == str(Path("..", "..", "boxing-wm", "seed0",
                                                                                 "agent-separable-64.pt"))
    frames = np.random.default_rng(0).integers(0, 256, (3, 64, 64, 3), dtype=np.uint8)
    shared = load_agent(az).vision(frames)
    encoder = torch.load(wm, weights_only=False)["encoder"]
    torch.save({**saved, "encoder": encoder, "vision_file": None}, az)  # as a run writes it: its own copy
    before, size = load_agent(az).vision(frames), az.stat().st_size
    assert torch.equal(before, shared)
    share_vision(az, wm)
    assert az.stat().st_size < size - 2_000_000  # the encoder's copy is gone
    assert torch.equal(load_agent(az).vision(frames), before)  # and the agent sees the same
    wm.write_bytes(wm.read_bytes() + b"changed")
    with pytest.raises(ValueError, match=r"sees through the vision of .*not the file it was trained with"):
        load_agent(az)
    other = tmp_path / "other.pt"
    imitation = torch.load(SHIPPED / "quick/boxing-wm-alphazero/seed0/agent-imitation.pt", weights_only=False)
    torch.save({**imitation, "encoder": encoder, "vision_file": None}, other)
    saved = torch.load(SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt", weights_only=False)
    torch.save({**saved, "encoder": {k: v + 1 for k, v in saved["encoder"].items()}}, wm)  # another encoder
    with pytest.raises(ValueError, match="does not see through the encoder of"):
        share_vision(other, wm)


def test_dreams_and_open_loops_want_one_action_per_frame(shipped):
    frames = np.zeros((20, 64, 64, 3), np.uint8)
    with pytest.raises(ValueError, match=r"one action per frame .*got 20 frames and 5 actions"):
        wmthesis.load("boxing-wm").dream(frames, [0] * 5, context=10, horizon=5)
    with pytest.raises(ValueError, match="20 frames are too few: context \\+ horizon needs 25"):
        wmthesis.load("boxing-wm").dream(frames, [0] * 20, context=20, horizon=5)
    with pytest.raises(ValueError, match=r"got 6 frames and 5 actions"):
        wmthesis.load("planet-boxing-agent").open_loop(np.zeros((6, 32, 32, 3), np.uint8), [0] * 5, context=3)


def test_a_decoder_ships_as_int8_weights_within_half_a_step_of_its_float_ones():
    from wmthesis.world_models.decoder import compact, expanded

    weight = torch.randn(64, 32, 5, 5)
    stored = compact(weight)
    assert stored["int8"].dtype == torch.int8 and stored["scale"].shape == (64,)
    step = stored["scale"].view(-1, 1, 1, 1)
    assert ((expanded(stored) - weight).abs() <= step / 2 + 1e-6).all() and not torch.equal(expanded(stored), weight)
    bias = torch.randn(7)
    assert expanded(compact(bias)).dtype == torch.float32 and torch.allclose(expanded(compact(bias)), bias, atol=1e-2)


def test_a_step_limited_play_seeds_each_bout_as_the_evaluation_did():
    """``play(bouts, max_steps=...)`` without a policy plays each bout's scored mind (its own
    noise seed), not one mind for every bout."""
    import gymnasium as gym

    from wmthesis.agents import TrainedAgent
    from wmthesis.core import Callback, ConstantMind

    class Pushes(ConstantMind, Callback):  # a mind that is its own callback, as the agents' are
        pass

    class Seeded(TrainedAgent):
        def env(self):
            return gym.make("CartPole-v1")

        def scored_seeds(self, bouts):
            return [11, 12][:bouts]

        def scored_minds(self, bouts):  # bout k's mind pushes action k, as if seeded so
            return [(seed, Pushes(2, k)) for k, seed in enumerate(self.scored_seeds(bouts))]

    agent = Seeded(Path("x.pt"), "toy", None, "smoke", 0, {})
    played = agent.play(bouts=2, max_steps=500)
    by_hand = []
    for k, seed in enumerate((11, 12)):
        env = gym.make("CartPole-v1")
        env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            _, reward, terminated, truncated, _ = env.step(k)
            total, done = total + reward, terminated or truncated
        by_hand.append(total)
    assert played == by_hand


def test_a_shipped_agent_loads_whatever_the_data_folder_and_one_trained_there_comes_first(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))  # outputs elsewhere: the shipped agents still load
    agent = wmthesis.load("boxing-wm")
    assert agent.path == SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt"
    assert not any(tmp_path.rglob("*.pt"))
    target = wmthesis.agent_file("boxing-wm")  # where a run here writes its agent: the data folder
    assert target == tmp_path / "quick/boxing-wm/seed0/agent-separable-64.pt"
    target.parent.mkdir(parents=True, exist_ok=True)
    shutil.copy(SHIPPED / "quick/boxing-wm/seed0/agent-separable-64.pt", target)
    assert wmthesis.load("boxing-wm").path == target


def test_the_headlines_read_the_committed_results_whatever_the_data_folder_and_say_when_none_are_there(tmp_path, monkeypatch):
    from wmthesis.summary import headlines

    monkeypatch.setenv("WMTHESIS_DATA", str(SHIPPED))
    committed_rows = {h["title"]: h["ours"] for h in headlines()}
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))  # a data folder of one's own: the repository's results still read
    assert {h["title"]: h["ours"] for h in headlines()} == committed_rows
    assert committed_rows["World Models on Boxing"]["n"] >= 10
    assert not any(tmp_path.iterdir())  # reading made no folder
    with pytest.warns(UserWarning, match=rf"no results under {tmp_path}: every headline reads 'not run yet'"):
        empty = headlines(folder=tmp_path)
    assert all(h["ours"] is None for h in empty)


def test_every_agent_plans_from_an_episode_you_give_it_as_it_would_have_while_playing(shipped):
    from wmthesis.core import Transition

    def episode(agent, steps=12):
        env = agent.env()
        frame, _ = env.reset(seed=3)
        frames, actions, rng = [frame], [], np.random.default_rng(3)
        for _ in range(steps):
            actions.append(int(rng.integers(env.action_space.n)))
            frames.append(env.step(actions[-1])[0])
        return frames, actions

    def played(mind, frames, actions):
        """The mind driven as loop drives it: plan at each frame, then the action taken."""
        mind.reset()
        for t, (frame, action) in enumerate(zip(frames[:-1], actions)):
            mind.plan(frame)
            mind.on_step_taken(t, Transition(frame, action, 0.0, frames[t + 1], False), {})
        return mind

    world_models = wmthesis.load("boxing-wm")
    frames, actions = episode(world_models)
    filtered = world_models.filter(frames, actions)
    assert np.array_equal(filtered.plan(frames[-1]), played(world_models.mind(), frames, actions).plan(frames[-1]))
    alphazero = wmthesis.load("boxing-wm-alphazero")
    frames, actions = episode(alphazero)
    filtered, by_loop = alphazero.filter(frames, actions, simulations=16), played(alphazero.mind(simulations=16), frames, actions)
    assert np.array_equal(filtered.h, by_loop.h) and np.array_equal(filtered.c, by_loop.c)  # the same memory state
    assert filtered.plan(frames[-1]).shape == (18,)
    planet = wmthesis.load("planet-boxing-agent")
    frames, actions = episode(planet)
    once, again = (planet.filter(frames, actions).plan(frames[-1]) for _ in range(2))
    assert once.shape == (18,) and np.array_equal(once, again)  # a fresh mind each time, seeded alike
    with pytest.raises(ValueError, match=r"the frames seen \(T \+ 1\) and the actions taken at all but the last"):
        planet.filter(frames, actions + [0])
    with pytest.raises(ValueError, match=r"a valid action is an integer in \[0, 17\]"):
        planet.filter(frames, actions[:-1] + [18])


def test_sokobans_one_step_prediction_is_one_call_beside_the_truth(shipped):
    sokoban = wmthesis.load("sokoban-search")
    level = "#######\n#@$ . #\n#  $. #\n#######"
    pushed, walked = sokoban.predict(level, 3), sokoban.predict(level, 5)  # push right; move down
    for out in (pushed, walked):
        assert out["frame"].dtype == np.uint8 and out["frame"].shape == out["truth"].shape == (16, 40, 3)
        assert np.array_equal(out["frame"], out["truth"])  # the shipped model gets these steps right
        assert out["reward"] == pytest.approx(-0.1, abs=1e-6) and out["done"] is False
    assert not np.array_equal(pushed["frame"], walked["frame"])
    with pytest.raises(ValueError, match=r"a valid action is an integer in \[0, 7\]"):
        sokoban.predict(level, 8)


@pytest.mark.parametrize("name", ["boxing-wm", "boxing-wm-alphazero", "planet-boxing-agent"])
def test_every_model_predicts_the_next_frame_and_reward_of_an_episode_you_give_it(name, shipped):
    agent = wmthesis.load(name)
    env = agent.env()
    frame, _ = env.reset(seed=5)
    frames, actions, rng = [frame], [], np.random.default_rng(5)
    for _ in range(16):
        actions.append(int(rng.integers(env.action_space.n)))
        frames.append(env.step(actions[-1])[0])
    out = agent.predict(frames[:-1], actions)
    truth = frames[-1].astype(float)
    assert out["frame"].dtype == np.uint8 and out["frame"].shape == frames[-1].shape and np.isfinite(out["reward"])
    assert np.abs(out["frame"] - truth).mean() < 0.5 * np.abs(truth).mean()  # the picture, not a blank
    with pytest.raises(ValueError, match="pass one action per frame, the last the one whose outcome is predicted"):
        agent.predict(frames[:-1], actions[:-1])


def test_the_alphazero_agent_dreams_as_the_world_models_agent_does(shipped):
    alphazero, world_models = wmthesis.load("boxing-wm-alphazero"), wmthesis.load("boxing-wm")
    env = alphazero.env()
    frame, _ = env.reset(seed=2)
    frames, actions, rng = [frame], [], np.random.default_rng(2)
    for _ in range(24):
        actions.append(int(rng.integers(18)))
        frames.append(env.step(actions[-1])[0])
    frames, actions = np.stack(frames[:-1]), np.asarray(actions)
    ours, theirs = alphazero.dream(frames, actions, 16, 8), world_models.dream(frames, actions, 16, 8)
    assert set(ours) == set(theirs) and ours["prediction"].shape == theirs["prediction"].shape == (8, 64, 64, 3)
    assert np.array_equal(ours["truth"], theirs["truth"]) and np.all(np.isfinite(ours["pixel_error"]))
    assert ours["latent_error"][0] < ours["latent_error"][-1]  # its own predictions drift
    with pytest.raises(ValueError, match="context \\+ horizon needs 30"):
        alphazero.dream(frames, actions, 20, 10)
