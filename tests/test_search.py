"""Random search over KL scale x free nats: reproducible suggestions, two worker processes on
one study (SQLite, and PostgreSQL when ``WMTHESIS_TEST_POSTGRES_URL`` is set, as in CI), a
killed worker, divergence, and the command line, all with smoke-sized trials."""
import dataclasses
import json
import os
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import matplotlib
import optuna
import pytest

matplotlib.use("Agg")

from wmthesis.__main__ import main  # noqa: E402
from wmthesis.planet.config import SearchConfig
from wmthesis.config import for_profile  # noqa: E402
from wmthesis.planet import tuning as tuning_module  # noqa: E402
from wmthesis.planet.tuning import (TrialSeededSampler, default_storage, load_study, make_storage, open_study,
                                    planned_settings, ranked, run_search, search_figure, storage_fingerprint,
                                    study_dir, study_name, trial_dir, trial_rows)
from wmthesis.utils import data_dir  # noqa: E402

POSTGRES = os.environ.get("WMTHESIS_TEST_POSTGRES_URL")
SMOKE = for_profile(SearchConfig, "smoke")


def fresh(storage: str, name: str, objective: str = "both") -> None:
    """Delete a study left by an earlier run (a developer's persistent PostgreSQL)."""
    try:
        optuna.delete_study(study_name=study_name(name, "smoke", objective), storage=make_storage(storage, SMOKE))
    except KeyError:
        pass


def test_suggestions_depend_only_on_seed_and_trial_number():
    first, again = planned_settings(SMOKE, 6), planned_settings(SMOKE, 6)
    assert first == again
    assert first != planned_settings(for_profile(SearchConfig, "smoke", seed=1), 6)
    assert all(SMOKE.kl_scale_low <= s["kl_scale"] <= SMOKE.kl_scale_high for s in first)
    assert all(SMOKE.free_nats_low <= s["free_nats"] <= SMOKE.free_nats_high for s in first)
    # a study asked out of order (as by several workers) still gives trial n the same setting
    study = optuna.create_study(sampler=TrialSeededSampler(SMOKE.seed))
    trials = [study.ask() for _ in range(6)]
    for trial in reversed(trials):
        assert trial.suggest_float("free_nats", SMOKE.free_nats_low, SMOKE.free_nats_high) == \
            first[trial.number]["free_nats"]
    # the thesis's best values lie inside the ranges
    assert SMOKE.kl_scale_low < 8e-3 < 3e-2 < SMOKE.kl_scale_high
    assert SMOKE.free_nats_low < 3 < 12 < SMOKE.free_nats_high


def test_trial_folders_are_keyed_by_storage(tmp_path, monkeypatch):
    """A study name in two storages gets two trial folders; one storage, however its password or
    relative SQLite path is spelt, gets one; the default storage's folder is the study's name."""
    monkeypatch.chdir(tmp_path)
    one, other = f"sqlite:///{tmp_path / 'one.db'}", f"sqlite:///{tmp_path / 'other.db'}"
    urls = (one, other, "sqlite:///one.db")
    studies = [open_study("planet-boxing", SMOKE, "smoke", url) for url in urls]
    first, second, again = (trial_dir(study, 3, url) for study, url in zip(studies, urls))
    name = study_name("planet-boxing", "smoke", SMOKE.objective)
    assert first != second and first == again
    assert first == data_dir("search", f"{name}-{storage_fingerprint(one)}", "trial-0003")
    postgres = "postgresql+psycopg2://user{}@host:5432/db"
    fingerprints = {storage_fingerprint(postgres.format(password)) for password in ("", ":secret", ":other")}
    assert len(fingerprints) == 1 and fingerprints.isdisjoint({storage_fingerprint(url) for url in urls})
    assert study_dir(name) == study_dir(name, default_storage()) == data_dir("search", name)


STORAGES = ["sqlite", pytest.param("postgresql", marks=pytest.mark.skipif(
    not POSTGRES, reason="WMTHESIS_TEST_POSTGRES_URL not set (.ci/run starts a PostgreSQL server and sets it)"))]


@pytest.mark.parametrize("backend", STORAGES)
def test_two_worker_processes_share_one_study(backend, tmp_path):
    storage = f"sqlite:///{tmp_path / 'studies.db'}" if backend == "sqlite" else POSTGRES
    fresh(storage, "planet-freeway")
    study = run_search("planet-freeway", trials=3, workers=2, storage=storage, profile="smoke")
    rows = [row for row in trial_rows(study) if not row["surplus"]]  # a worker that lost the race for the last place
    assert [row["state"] for row in rows] == ["COMPLETE"] * 3
    assert len({row["worker"] for row in rows}) == 2, "both worker processes ran trials"
    planned = planned_settings(SMOKE, 3)
    for row in rows:
        assert {k: row[k] for k in ("kl_scale", "free_nats")} == planned[row["number"]]
        folder = Path(row["folder"])
        assert folder.parent == study_dir(study.study_name, storage)
        metrics = json.loads((folder / "metrics.json").read_text())
        assert metrics["error"] == row["error"] and metrics["score"] == row["score"]
        assert (folder / "open_loop.png").stat().st_size > 1000
    assert ranked(study)[0]["state"] == "COMPLETE"
    search_figure(study, "planet-freeway", "error")
    # the same command again: the study is finished, nothing runs (the first run may have left a surplus trial)
    before = len(study.trials)
    assert len(run_search("planet-freeway", trials=3, workers=2, storage=storage, profile="smoke").trials) == before


def _has_heartbeat(database: Path, trial_id: int) -> bool:
    """Whether the trial's worker has beaten once (optuna's ``trial_heartbeats`` table). A
    worker killed in the instant between creating its trial and its first beat leaves a
    trial that no heartbeat check can tell from a live one, so the test kills after it."""
    with sqlite3.connect(database) as db:
        return db.execute("SELECT COUNT(*) FROM trial_heartbeats WHERE trial_id = ?", (trial_id,)).fetchone()[0] > 0


def test_a_killed_worker_leaves_the_study_consistent_and_it_resumes(tmp_path):
    storage = f"sqlite:///{tmp_path / 'studies.db'}"
    command = [sys.executable, "-m", "wmthesis", "search", "planet-boxing", "--trials", "2", "--workers", "1",
               "--storage", storage, "--profile", "smoke"]
    worker = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        states = []
        while worker.poll() is None:   # kill it mid-way through its second trial: wait on that, not on a clock
            time.sleep(0.2)
            try:
                trials = load_study("planet-boxing", "smoke", storage=storage).trials
            except KeyError:
                continue
            states = [t.state for t in trials]
            if (states == [optuna.trial.TrialState.COMPLETE, optuna.trial.TrialState.RUNNING]
                    and _has_heartbeat(tmp_path / "studies.db", trials[1]._trial_id)):
                break
        else:
            pytest.fail(f"the worker ended (status {worker.returncode}) before it was caught in its second trial "
                        f"(states {states})")
        worker.send_signal(signal.SIGKILL)
        worker.wait(10)
    finally:
        worker.kill()
    before = load_study("planet-boxing", "smoke", storage=storage).trials
    assert [t.state.name for t in before] == ["COMPLETE", "RUNNING"]
    study = run_search("planet-boxing", trials=2, storage=storage, profile="smoke")
    after = study.trials
    assert [t.state.name for t in after] == ["COMPLETE", "FAIL", "COMPLETE"]
    assert after[0].values == before[0].values and after[0].datetime_complete == before[0].datetime_complete
    assert after[2].params == planned_settings(SMOKE, 3)[2]


def test_a_diverging_trial_is_pruned_and_counts(tmp_path, monkeypatch):
    def diverge(*args, **kwargs):
        raise FloatingPointError("non-finite loss at update 3")

    monkeypatch.setattr(tuning_module, "train_planet", diverge)
    study = run_search("planet-boxing", trials=1, storage=f"sqlite:///{tmp_path / 's.db'}", profile="smoke",
                       objective="score")
    (row,) = trial_rows(study)
    assert row["state"] == "PRUNED" and "update 3" in row["diverged"]


def test_the_command_line_runs_a_search_and_refuses_changed_settings(tmp_path, capsys):
    storage = f"sqlite:///{tmp_path / 's.db'}"
    assert main(["search", "planet-freeway", "--trials", "1", "--storage", storage, "--profile", "smoke",
                 "--objective", "error"]) == 0
    out = capsys.readouterr().out
    assert "1 complete" in out and "best: trial 0" in out and "thesis: KL scale 0.008, free nats 3" in out
    with pytest.raises(ValueError, match="seed"):
        open_study("planet-freeway", for_profile(SearchConfig, "smoke", objective="error", seed=5), "smoke", storage)


def test_trials_take_the_search_budget_and_episode_cap(tmp_path, monkeypatch):
    from wmthesis.data import EpisodeStore

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))        # trial folders of its own

    study = run_search("planet-freeway", trials=1, storage=f"sqlite:///{tmp_path / 's.db'}", profile="smoke",
                       objective="error", env_steps=40, max_episode_steps=12)
    (row,) = trial_rows(study)
    with EpisodeStore(Path(row["folder"]) / "run" / "episodes.h5") as store:
        lengths = store.episode_lengths
        assert lengths.max() == 12 and store.num_steps >= 40
    assert json.loads((Path(row["folder"]) / "metrics.json").read_text())["env_steps"] >= 40


def test_a_trial_racing_for_the_last_place_is_surplus(tmp_path):
    from optuna.trial import TrialState

    from wmthesis.planet.tuning import surplus_trial

    study = optuna.create_study(storage=f"sqlite:///{tmp_path / 's.db'}", directions=["maximize"])
    cfg = dataclasses.replace(SMOKE, trials=2)
    study.tell(study.ask(), 1.0)
    a, b = study.ask(), study.ask()  # two workers start a trial at once for the last place
    assert not surplus_trial(a, cfg) and surplus_trial(b, cfg)
    study.tell(b, state=TrialState.FAIL)
    study.tell(a, state=TrialState.FAIL)  # a's worker dies: the place is free again
    assert not surplus_trial(study.ask(), cfg)


def test_trials_share_held_out_episodes_and_the_extremes_are_trained_again(tmp_path):
    """Every trial is measured on the same held-out episodes (so the baselines' errors agree to
    the bit); the best and the worst setting get a second seed, and the verdict is gap > spread."""
    from wmthesis.planet.tuning import confirm_extremes

    storage = f"sqlite:///{tmp_path / 'extremes.db'}"
    study = run_search("planet-boxing", trials=2, workers=1, storage=storage, profile="smoke", objective="error")
    rows = [json.loads((Path(row["folder"]) / "metrics.json").read_text()) for row in trial_rows(study)]
    assert len(rows) == 2 and rows[0]["repeat_last_error"] == rows[1]["repeat_last_error"] > 0
    assert all(row["error"] == row["horizon_errors"][row["horizon"] - 1] for row in rows)
    result = confirm_extremes("planet-boxing", study, storage=storage, progress=False)
    order = sorted(rows, key=lambda row: row["error"])
    assert result["best"]["number"] == order[0]["trial"] and result["worst"]["number"] == order[-1]["trial"]
    assert result["best"]["values"][0] == order[0]["error"] and result["seeds"] == [SMOKE.seed, SMOKE.seed + 1]
    spread = max(abs(result[k]["values"][0] - result[k]["values"][1]) for k in ("best", "worst"))
    assert result["spread"] == pytest.approx(spread) and result["discriminates"] == (result["gap"] > spread)
    second = Path(trial_rows(study)[result["best"]["number"]]["folder"]) / f"seed{SMOKE.seed + 1}" / "checkpoint.pt"
    assert second.exists()
    assert json.loads((study_dir(study.study_name, storage) / "confirmation.json").read_text()) == result
    # the search as an experiment: one metrics.json, a summary row that is the best trial's error x 1000
    from wmthesis.planet.search_run import SCALE, write_search_metrics
    from wmthesis.summary import read_runs

    metrics = write_search_metrics(study, result, "smoke", 0, 1.0)
    (run,) = [r for r in read_runs() if (r.experiment, r.profile) == ("planet-boxing-search", "smoke")]
    assert run.score == SCALE * order[0]["error"] and run.wall_seconds == metrics["first_run_wall_seconds"] > 0
    assert metrics["best"]["number"] == order[0]["trial"] and json.dumps(metrics, allow_nan=False)  # strict JSON
