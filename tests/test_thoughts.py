"""Recordings of what a shipped agent thinks beside what happened (`play --record`): read back with
rerun's own reader, their imagined frames are the library's own decodes, aligned with the step
they predict, and an interrupted or decoder-less recording still opens."""
from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

import wmthesis
from wmthesis.__main__ import main
from wmthesis.metrics import horizon_errors
from wmthesis.thoughts import read_recording

SHIPPED = Path(__file__).resolve().parents[1] / "data"


@pytest.fixture
def shipped(monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(SHIPPED))


def at(recording: dict, entity: str, step: int):
    """The value an entity holds at ``step``."""
    entry = recording[entity]
    return entry["values"][entry["steps"].index(step)]


def test_a_world_models_recording_shows_its_dream_aligned_with_reality(tmp_path, shipped):
    from wmthesis.world_models.trained import dream_path

    agent = wmthesis.load("boxing-wm")
    agent.max_steps = 40
    out = agent.record(1, tmp_path / "bout.rrd")
    recording = read_recording(tmp_path / "bout.rrd")
    assert {"/reality", "/model/seen", "/imagination/1", "/imagination/4", "/imagination/8", "/error/8",
            "/reward/real", "/reward/imagined", "/scores/controller"} <= set(recording)
    assert recording["/reality"]["steps"] == list(range(41)) and out["steps"] == 41  # 40 steps and the last frame
    assert recording["/reward/real"]["steps"] == recording["/reward/imagined"]["steps"] == list(range(1, 41))
    assert recording["/imagination/8"]["steps"] == list(range(8, 41))  # drawn at the step they predict
    assert at(recording, "/imagination/4", 4).shape == (64, 64, 3) and len(at(recording, "/scores/controller", 0)) == 18

    # the first step's dream, made again with the library's own parts, is what the recording holds
    env, mind = agent.env(), agent.mind()
    seed = agent.scored_seeds(1)[0]
    frame, _ = env.reset(seed=seed)
    mind.reset()
    mind.plan(frame)
    latents, rewards, scores = dream_path(agent.controller, agent.memory, mind.z, mind.h, mind.state, 8)
    assert np.array_equal(at(recording, "/reality", 0), frame)
    assert np.array_equal(at(recording, "/model/seen", 0), agent.vision.decode(mind.z)[0])
    assert np.array_equal(at(recording, "/imagination/1", 1), agent.vision.decode(latents[:, 0])[0])
    for j in (4, 8):  # dreamed in a batch of steps: the float sums may differ in their last bit, a pixel by one level
        difference = at(recording, f"/imagination/{j}", j).astype(int) - agent.vision.decode(latents[:, j - 1])[0]
        assert np.abs(difference).max() <= 1
    assert at(recording, "/reward/imagined", 1) == pytest.approx(float(rewards[0, 0]), abs=1e-6)
    np.testing.assert_allclose(at(recording, "/scores/controller", 0), scores[0], atol=1e-6)

    # its error is the model study's measure, frame against the frame that came, and its mean is printed
    for j in (1, 8):
        errors = [horizon_errors(at(recording, "/reality", s)[None], at(recording, f"/imagination/{j}", s)[None])[0]
                  for s in recording[f"/error/{j}"]["steps"]]
        np.testing.assert_allclose(recording[f"/error/{j}"]["values"], errors, rtol=1e-9)
        assert out["errors"][j] == pytest.approx(np.mean(errors))
    assert out["errors"][8] > out["errors"][1] > 0  # imagination parts from reality the further it looks
    seen = [horizon_errors(at(recording, "/reality", s)[None], at(recording, "/model/seen", s)[None])[0]
            for s in recording["/model/seen"]["steps"]]
    assert out["reconstruction"] == pytest.approx(np.mean(seen)) and 0 < out["reconstruction"] < out["errors"][8]
    from wmthesis.play import imagination_line

    assert imagination_line(out).endswith(f"; the reconstruction of the frame itself: {np.mean(seen):.4f}")


def test_a_world_models_agent_dreams_the_same_in_a_batch_as_alone(shipped):
    agent = wmthesis.load("boxing-wm")
    env, mind = agent.env(), agent.mind()
    frame, _ = env.reset(seed=agent.scored_seeds(1)[0])
    snapshots = []
    for action in (0, 1, 2):
        mind.plan(frame)
        snapshots.append(agent.snapshot(mind))
        frame, *_ = env.step(action)
        mind.on_step_taken(0, type("T", (), {"action": action})(), {})
    together, alone = agent.thoughts(snapshots), [agent.thoughts([s])[0] for s in snapshots]
    for a, b in zip(together, alone):
        np.testing.assert_allclose(a.imagined_rewards, b.imagined_rewards, atol=1e-5)
        assert sorted(a.imagined) == [1, 4, 8]
        assert max(int(np.abs(a.imagined[j].astype(int) - b.imagined[j]).max()) for j in a.imagined) <= 1


def test_an_alphazero_recording_holds_the_roots_visits_and_its_principal_variation(tmp_path, shipped):
    from wmthesis.alphazero.trained import principal_variation

    agent = wmthesis.load("boxing-wm-alphazero")
    agent.max_steps = 3
    agent.record(1, tmp_path / "az.rrd")
    recording = read_recording(tmp_path / "az.rrd")
    visits, q, prior = (at(recording, f"/scores/{name}", 0) for name in ("visits", "q", "prior"))
    assert len(visits) == len(q) == len(prior) == 18 and prior.sum() == pytest.approx(1.0)
    assert 0 < visits.sum() <= agent.config.simulations
    depth = int(at(recording, "/values/depth", 0))
    assert 1 <= depth <= agent.horizon and at(recording, "/imagination/1", 1).shape == (64, 64, 3)

    mind = agent.scored_minds(1)[0][1]  # the first decision again: its principal variation's first frame
    env = agent.env()
    frame, _ = env.reset(seed=agent.scored_minds(1)[0][0])
    mind.on_episode_start(0, False)
    mind.plan(frame, train_mode=False)
    latents, rewards = principal_variation(mind.mcts.root, agent.horizon)
    assert len(latents) == depth
    assert np.array_equal(at(recording, "/imagination/1", 1), agent.vision.decode(latents[0][None])[0])
    assert at(recording, "/reward/imagined", 1) == pytest.approx(rewards[0])


def test_a_planet_recording_shows_the_plan_the_planner_chose_imagined(tmp_path, shipped):
    from wmthesis.planet.prediction import planned_path
    from wmthesis.planet.rssm import frames_out

    agent = wmthesis.load("planet-boxing-agent")
    agent.max_steps = agent.config.horizon + 1
    agent.record(1, tmp_path / "planet.rrd")
    recording = read_recording(tmp_path / "planet.rrd")
    horizon, size = agent.config.horizon, agent.config.frame_size
    assert {f"/imagination/{j}" for j in range(1, horizon + 1)} <= set(recording)
    assert len(at(recording, "/series/cem_elites", 0)) == agent.config.iterations
    assert at(recording, "/model/seen", 0).shape == (size, size, 3)

    env_seed, mind = agent.scored_minds(1)[0]
    frame, _ = agent.env().reset(seed=env_seed)
    mind.plan(frame)
    beliefs, states, rewards = planned_path(agent.model, mind.belief, mind.state, mind.last_plan.mean.argmax(-1))
    frames = frames_out(agent.model.decode(beliefs, states), agent.config.bits).numpy()
    assert np.array_equal(at(recording, "/imagination/1", 1), frames[0])
    assert np.array_equal(at(recording, "/imagination/2", 2), frames[1])
    assert at(recording, "/reward/imagined", 1) == pytest.approx(float(rewards[0]), abs=1e-6)
    elites = at(recording, "/series/cem_elites", 0)
    assert elites[-1] >= elites[0] - 1e-6  # CEM's elites do not get worse as it refits


def test_a_value_agent_records_its_q_per_first_action(tmp_path, shipped):
    agent = wmthesis.load("planet-boxing-value")
    agent.max_steps = 2
    agent.record(1, tmp_path / "value.rrd")
    recording = read_recording(tmp_path / "value.rrd")
    assert len(at(recording, "/scores/value_q", 0)) == 18 and "/imagination/1" in recording


def test_a_sokoban_recording_draws_the_plan_and_the_boards_its_model_predicts(tmp_path, shipped):
    agent = wmthesis.load("sokoban-search")
    out = agent.record(1, tmp_path / "level.rrd")
    recording = read_recording(tmp_path / "level.rrd")
    steps = out["plays"][0]["steps"]
    assert out["plays"][0]["solved"] and recording["/reality"]["steps"] == list(range(steps + 1))
    plan = at(recording, "/reality/plan", 0)
    assert plan.shape == (steps + 1, 2)  # the player's path along the whole plan, found at the first step
    assert at(recording, "/values/plan_length", 0) == steps and at(recording, "/values/expanded", 0) > 0
    # the learned model predicts this level's boards exactly: every imagined board is the one that came
    for j in (1, 8):
        assert recording[f"/error/{j}"]["steps"] == list(range(j, steps + 1))
        assert max(recording[f"/error/{j}"]["values"]) == 0.0 and out["errors"][j] == 0.0


def test_an_agent_without_its_decoder_records_the_rest_and_says_what_is_left_out(tmp_path, monkeypatch, capsys):
    folder = tmp_path / "quick" / "boxing-wm" / "seed0"
    folder.mkdir(parents=True)
    shutil.copy(SHIPPED / "quick" / "boxing-wm" / "seed0" / "agent-separable-64.pt", folder)
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    agent = wmthesis.load("boxing-wm")
    agent.max_steps = 10
    assert "left out: the vision's reconstructions and the dream's frames" in agent.left_out()
    agent.record(1, tmp_path / "bout.rrd")
    recording = read_recording(tmp_path / "bout.rrd")
    assert "/model/seen" not in recording and not any(e.startswith("/imagination") for e in recording)
    assert recording["/reward/imagined"]["steps"] == list(range(1, 11)) and "/scores/controller" in recording


def test_an_interrupted_recording_keeps_what_was_played_and_opens(tmp_path, shipped, monkeypatch, capsys):
    agent = wmthesis.load("boxing-wm")
    thoughts, calls = agent.thoughts, []

    def interrupted(snapshots):
        calls.append(len(snapshots))
        if len(calls) == 3:
            raise KeyboardInterrupt
        return thoughts(snapshots)

    agent.thoughts = interrupted
    with pytest.raises(KeyboardInterrupt):
        agent.record(1, tmp_path / "cut.rrd")
    recording = read_recording(tmp_path / "cut.rrd")
    assert recording["/reality"]["steps"] == list(range(64))  # two batches of 32 steps were written

    monkeypatch.setattr("wmthesis.play.play", lambda *a, **k: (_ for _ in ()).throw(KeyboardInterrupt))
    assert main(["play", "boxing-wm", "--record", str(tmp_path / "x.rrd")]) == 130
    assert capsys.readouterr().err.strip().splitlines() == [f"play interrupted: what was played is kept in {tmp_path / 'x.rrd'}"]


def test_a_recording_path_is_refused_before_anything_plays(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("wmthesis.agents.load", lambda *a, **k: pytest.fail("it loaded an agent"))
    (tmp_path / "folder.rrd").mkdir()
    for path, says in ((tmp_path / "folder.rrd", "is a folder"), (tmp_path / "x", "name a .rrd file"),
                       (tmp_path / "no" / "x.rrd", "cannot be written")):
        assert main(["play", "boxing-wm", "--record", str(path)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and says in err[0] and str(path) in err[0]


def test_torch_stays_untouched_by_the_recorders_own_module():
    import subprocess
    import sys

    code = "import sys, wmthesis.thoughts; print('torch' in sys.modules)"
    assert subprocess.run([sys.executable, "-c", code], capture_output=True, text=True).stdout.strip() == "False"
    assert torch.__version__  # the tests themselves use it
