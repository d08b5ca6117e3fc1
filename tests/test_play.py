"""`play`: a shipped agent plays its experiment's own evaluation levels with no training, and
refuses what it cannot do before anything loads or plays."""
from __future__ import annotations

import json
from pathlib import Path

import cv2
import pytest
import torch

import wmthesis.play as play_module
from wmthesis.__main__ import main
from wmthesis.experiments.sokoban_search import EVAL_PURPOSE
from wmthesis.sokoban_search.agent import level_seeds
from wmthesis.sokoban_search.evaluation import check_solutions


def test_the_shipped_sokoban_agent_plays_the_experiments_first_evaluation_levels(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(Path(__file__).resolve().parents[1] / "data"))  # what the repository ships
    result = play_module.play("sokoban-search", profile="quick", seed=0, bouts=2, record=tmp_path / "plays.rrd",
                              video=tmp_path / "plays.mp4", on_play=lambda line: None)
    assert [p["seed"] for p in result["plays"]] == level_seeds(0, EVAL_PURPOSE, 500)[:2]  # the summary's levels
    solved = [p for p in result["plays"] if p["solved"]]
    assert all(check_solutions("sokoban", solved)) and result["score"] == len(solved) / 2  # replayed in the real game
    video = cv2.VideoCapture(str(tmp_path / "plays.mp4"))
    frames = int(video.get(cv2.CAP_PROP_FRAME_COUNT))
    video.release()
    assert frames == sum(p["steps"] + 1 for p in result["plays"]) and (tmp_path / "plays.rrd").stat().st_size > 0


def test_play_refuses_what_it_cannot_do_before_anything_plays(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr("wmthesis.agents.load", lambda *a, **k: pytest.fail("it loaded an agent"))
    assert main(["play", "sokoban-search", "--video", str(tmp_path / "missing" / "x.mp4")]) == 2
    assert "x.mp4 cannot be written: its folder" in capsys.readouterr().err
    assert main(["play", "sokoban-search", "--record", str(tmp_path / "x.mp4")]) == 2
    assert "name a .rrd file" in capsys.readouterr().err
    assert main(["play", "planet-boxing-study"]) == 2
    assert "planet-boxing-study has no agent that plays" in capsys.readouterr().err
    assert main(["play", "sokoban-search", "--variant", "x"]) == 2
    assert "has no variants" in capsys.readouterr().err
    assert main(["play", "boxing-wm", "--variant", "x"]) == 2
    assert "unknown variant 'x' of boxing-wm" in capsys.readouterr().err


def test_play_names_a_missing_agent_and_the_command_that_trains_it(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    assert main(["play", "sokoban-search", "--profile", "smoke", "--seed", "3", "--bouts", "1"]) == 2
    err = capsys.readouterr().err
    assert "no trained sokoban-search agent at" in err and "reproduce sokoban-search --profile smoke --seed 3`" in err


def test_a_boxing_agent_plays_the_bouts_its_score_was_measured_on(tmp_path, monkeypatch, capsys):
    """A smoke run's agent file (vision's encoder, memory, controller: about 3 MB here) plays its
    evaluation bouts to the same returns; its video has every bout's frames."""
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    from wmthesis.experiments import reproduce
    from wmthesis.world_models.agent import load_agent

    metrics = reproduce("boxing-wm", "smoke", 0, progress=False)
    agent = load_agent(metrics["files"]["agent"])
    assert agent.params.shape == (18 * (16 + 32 + 1),) and agent.info["commit"] and agent.info["generation"] == 2
    result = play_module.play("boxing-wm", profile="smoke", bouts=2, video=tmp_path / "bouts.mp4",
                              record=tmp_path / "bouts.rrd", on_play=lambda line: None)
    assert [p["return"] for p in result["plays"]] == metrics["returns"]
    assert result["score"] == metrics["score"]["mean"] and result["variant"] == "separable-64"
    video = cv2.VideoCapture(str(tmp_path / "bouts.mp4"))
    frames, width = int(video.get(cv2.CAP_PROP_FRAME_COUNT)), int(video.get(cv2.CAP_PROP_FRAME_WIDTH))
    video.release()
    assert frames == sum(p["steps"] + 1 for p in result["plays"]) and width == 5 * 64 * 4  # reality, its view, 3 imagined
    assert main(["play", "boxing-wm", "--profile", "smoke", "--seed", "4"]) == 2
    assert "reproduce boxing-wm --profile smoke --seed 4`" in capsys.readouterr().err
    # its metrics written again by a resumed call (the world model trained and every generation
    # evolved before): the time it states for a run from scratch counts the sittings before this call
    Path(metrics["files"]["recording"]).with_name("metrics.json").unlink()
    again = reproduce("boxing-wm", "smoke", 0, progress=False)
    assert again["returns"] == metrics["returns"]
    from wmthesis.training import trained_seconds

    evolved = sum(g["seconds"] for g in metrics["controller_curve"])
    work = Path(metrics["files"]["agent"]).parent
    trained = trained_seconds(work / "vision.pt") + trained_seconds(work / "memory-mdn.pt")
    assert evolved > 0 and trained > 0
    assert again["first_run_wall_seconds"] > again["wall_seconds"] + 0.5 * (evolved + trained)
    Path(metrics["files"]["agent"]).write_bytes(b"not an agent")
    with pytest.raises(ValueError, match=r"cannot read .*agent-separable-64\.pt"):
        load_agent(metrics["files"]["agent"])


def test_an_alphazero_agent_searches_its_evaluation_games_to_the_same_scores(tmp_path, monkeypatch, capsys):
    """The imitation variant's agent file (vision's encoder, deterministic memory, the search's
    heads) replays the evaluation games its run scored, search and all; another budget plays."""
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    from wmthesis.alphazero.agent import load_agent
    from wmthesis.experiments import reproduce
    from wmthesis.utils import read_pickle

    reproduce("boxing-wm-alphazero", "smoke", 0, "imitation", progress=False)
    work = tmp_path / "smoke" / "boxing-wm-alphazero" / "seed0"
    scored = [g.score for g in read_pickle(work / "imitation" / "evaluation.pkl")["games"]]
    result = play_module.play("boxing-wm-alphazero", profile="smoke", variant="imitation", bouts=len(scored),
                              video=tmp_path / "bouts.mp4", on_play=lambda line: None)
    assert [p["return"] for p in result["plays"]] == scored and result["variant"] == "imitation"
    video = cv2.VideoCapture(str(tmp_path / "bouts.mp4"))
    assert int(video.get(cv2.CAP_PROP_FRAME_COUNT)) > 0
    video.release()
    agent = load_agent(work / "agent-imitation.pt")
    assert agent.info["variant"] == "imitation" and agent.mind(simulations=3).config.simulations == 3
    assert main(["play", "boxing-wm-alphazero", "--profile", "smoke", "--variant", "unchanged"]) == 2
    assert "reproduce boxing-wm-alphazero --profile smoke --seed 0 --variant unchanged`" in capsys.readouterr().err


def test_a_planet_value_agent_plays_the_bouts_its_score_was_measured_on(tmp_path, monkeypatch):
    """The value run's agent file (PlaNet's model without its decoder, the value, the planner)
    replays its CEM-with-value bouts to the same returns."""
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    from wmthesis.experiments import reproduce
    from wmthesis.planet.agent_file import load_agent
    from wmthesis.value.shipped import load_value_agent

    metrics = reproduce("planet-boxing-value", "smoke", 0, progress=False)
    saved_metrics = tmp_path / "results" / "planet-boxing-value" / "smoke-seed0" / "lean-value-rewards-0.7" / "metrics.json"
    for planet, kept in ((metrics["planet"], True), ({**metrics["planet"], "mean": 99.0}, False)):  # a model trained again
        saved_metrics.write_text(json.dumps({**metrics, "planet": planet, "first_run_wall_seconds": 1e6}))
        again = reproduce("planet-boxing-value", "smoke", 0, progress=False)  # cached: it plays nothing again
        assert (again["first_run_wall_seconds"] == 1e6) == kept and again["value"] == metrics["value"]
    saved_metrics.unlink()  # written again by a call that fits nothing: the rounds' sittings count
    again = reproduce("planet-boxing-value", "smoke", 0, progress=False)
    import torch

    rounds = torch.load(next(tmp_path.rglob("value.pt")), weights_only=False)["seconds"]
    assert rounds > 0 and again["first_run_wall_seconds"] > again["wall_seconds"] + 0.5 * rounds
    result = play_module.play("planet-boxing-value", profile="smoke", bouts=2, record=tmp_path / "bouts.rrd",
                              on_play=lambda line: None)
    assert [p["return"] for p in result["plays"]] == metrics["value_planner"]["returns"][:2]
    assert result["variant"] == "lean-value-rewards-0.7" and (tmp_path / "bouts.rrd").stat().st_size > 0
    path = tmp_path / "smoke" / "planet-boxing-value" / "lean-value-rewards-0.7-seed0" / "agent.pt"
    agent = load_value_agent(path)
    with pytest.raises(ValueError, match="is a learned value's agent: wmthesis.value.shipped.load_value_agent reads it"):
        load_agent(path)  # PlaNet's own reader refuses it, naming the one that reads it
    assert agent.info["bouts"] == metrics["bouts"] and agent.planner.discount == 0.7
    assert not any(k.startswith("decoder.") for k in torch.load(path, weights_only=False)["model"])  # left behind
    cem = reproduce("planet-boxing-agent", "smoke", 0, progress=False)  # the model's own agent (made first, cached)
    alone = play_module.play("planet-boxing-agent", profile="smoke", bouts=2, on_play=lambda line: None)
    assert [p["return"] for p in alone["plays"]] == cem["agent"]["returns"][:2]
    saved = torch.load(path, weights_only=False)  # rides on the PlaNet agent's file; the value in half precision
    assert saved["model"] == {} and saved["model_file"]["path"] == str(Path("..", "..", "planet-boxing-agent", "seed0", "agent.pt"))
    assert {t.dtype for t in saved["value"]["state"].values()} == {torch.float16}
    base = tmp_path / "smoke" / "planet-boxing-agent" / "seed0" / "agent.pt"
    base.write_bytes(base.read_bytes() + b"changed")
    with pytest.raises(ValueError, match="not the file it was fitted on"):
        load_value_agent(path)


def test_a_fresh_clone_fits_a_value_on_the_planet_agent_that_ships(tmp_path, monkeypatch):
    """Where a PlaNet run's agent file and metrics ship but its checkpoint is not here, a value
    builds on that agent (no PlaNet training), whose model plans but refuses to decode."""
    import wmthesis.runs as run_store
    from wmthesis.experiments import reproduce
    from wmthesis.planet.train import load_planet
    from wmthesis.value.comparison import frozen_agent

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path / "trained"))
    metrics = reproduce("planet-boxing-agent", "smoke", 0, progress=False)
    clone = tmp_path / "clone"
    for part in ("smoke/planet-boxing-agent/seed0/agent.pt", "results/planet-boxing-agent/smoke-seed0/metrics.json"):
        (clone / part).parent.mkdir(parents=True)
        (clone / part).write_bytes((tmp_path / "trained" / part).read_bytes())
    monkeypatch.setenv("WMTHESIS_DATA", str(clone))
    monkeypatch.setattr(run_store, "built_on", lambda *args, **kwargs: pytest.fail("PlaNet trained again"))
    found, work = frozen_agent("planet-boxing-agent", "smoke", 0)
    assert found == json.loads(json.dumps(metrics)) and work == clone / "smoke" / "planet-boxing-agent" / "seed0"
    model, _, meta = load_planet(work)
    assert meta == {"shipped": str(work / "agent.pt")}
    belief, state = torch.zeros(1, model.belief_size), torch.zeros(1, model.state_size)
    trained, _, _ = load_planet(tmp_path / "trained" / "smoke" / "planet-boxing-agent" / "seed0")
    assert torch.equal(model.reward(belief, state), trained.reward(belief, state))
    with pytest.raises(RuntimeError, match="agent.pt ships no observation decoder"):
        model.decode(belief, state)
