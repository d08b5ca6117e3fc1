"""PlaNet experiments end to end (smoke profile): variant checking, artifacts, resuming."""
import json
import time
from pathlib import Path

import pytest

from wmthesis.config import for_profile
from wmthesis.experiments import reproduce
from wmthesis.planet.config import PlanetEvaluationConfig


def test_a_wrong_variant_fails_listing_the_valid_ones():
    with pytest.raises(ValueError, match="nope.*unchanged, action-repeat, decoder-variance, free-nats"):
        reproduce("planet-boxing", "smoke", variant="nope")
    with pytest.raises(ValueError, match="freeway-tuned, long-horizon"):
        reproduce("planet-freeway", "smoke", variant="free-nats")  # a Boxing variant


def test_smoke_sokoban_writes_its_results_and_resumes(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    started = time.time()
    metrics = reproduce("planet-sokoban", "smoke", seed=1, progress=False)
    assert metrics["wall_seconds"] <= time.time() - started + 0.1  # the training is counted once

    out = tmp_path / "results" / "planet-sokoban" / "smoke-seed1" / "unchanged"
    assert json.loads((out / "metrics.json").read_text()) == json.loads(json.dumps(metrics, default=float))
    assert metrics["variant"] == "unchanged" and metrics["profile"] == "smoke"
    assert metrics["score"]["episodes"] == for_profile(PlanetEvaluationConfig, "smoke").episodes
    open_loop = metrics["open_loop"]
    assert len(open_loop["mse"]) == open_loop["horizon"]
    assert open_loop["error_at_cutoff"] == open_loop["mse"][open_loop["cutoff"] - 1] >= 0
    files = [Path(f) for f in [*metrics["files"]["figures"], metrics["files"]["recording"]]]
    assert {f.name for f in files} == {"open_loop.png", "horizon_error.png", "learning_curve.png", "open_loop.rrd"}
    assert all(f.parent == out and f.stat().st_size > 0 for f in files)

    checkpoint = tmp_path / "smoke" / "planet-sokoban" / "unchanged-seed1" / "checkpoint.pt"
    before = checkpoint.stat().st_mtime_ns
    again = reproduce("planet-sokoban", "smoke", seed=1, progress=False)
    assert checkpoint.stat().st_mtime_ns == before  # no retraining
    assert again == json.loads(json.dumps(metrics, default=float))


def test_an_action_repeat_variant_gets_the_same_frames(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    metrics = reproduce("planet-boxing", "smoke", variant="action-repeat", progress=False)
    config = metrics["config"]
    assert config["action_repeat"] == 8 and config["env_steps"] == 80 * 4 // 8   # smoke: 80 steps at repeat 4
    assert metrics["env_steps"] >= 40 and metrics["updates"] > 0                  # one planner episode at least
