"""Seed sweeps on Ray and the results table: runs as Ray tasks (a local Ray), a run that raises
is reported while the others finish, a killed worker's run is retried and resumes, re-running
runs only what is missing; the summary's arithmetic against a hand computation; bad input."""
import json
import math
import os
import signal
import sys
import threading
import time

import pytest

from wmthesis.__main__ import main
from wmthesis.experiments import reproduce
from wmthesis.headline import ablation_rows
from wmthesis.runs import first_run_seconds
from wmthesis.summary import aggregate, read_runs, write_summary
from wmthesis.sweep import SweepRun, finished, parse_runs, parse_seeds, start_ray, sweep


# ---------------------------------------------------------------------------- without Ray
def test_seeds_and_runs_are_parsed_and_bad_ones_refused():
    assert parse_seeds("0-4") == [0, 1, 2, 3, 4] and parse_seeds("0,2,7") == [0, 2, 7] and parse_seeds("3") == [3]
    assert parse_seeds("0-2,1") == [0, 1, 2]
    for bad in ("3-1", "x", "1-", "-1", ""):
        with pytest.raises(ValueError, match="--seeds"):
            parse_seeds(bad)
    runs = parse_runs(["boxing-wm", "planet-freeway:long-horizon"], [0, 1])
    assert runs == [SweepRun("boxing-wm", None, 0), SweepRun("boxing-wm", None, 1),
                    SweepRun("planet-freeway", "long-horizon", 0), SweepRun("planet-freeway", "long-horizon", 1)]
    with pytest.raises(ValueError, match="valid: freeway-tuned, long-horizon"):
        parse_runs(["planet-freeway:nope"], [0])
    with pytest.raises(ValueError, match="has no variants"):
        parse_runs(["planet-boxing-agent:x"], [0])
    with pytest.raises(ValueError, match="unknown variant 'x' of boxing-wm; valid: population-16, separable-64"):
        parse_runs(["boxing-wm:x"], [0])
    assert parse_runs(["planet-boxing-value:lean"], [2]) == [SweepRun("planet-boxing-value", "lean", 2)]
    with pytest.raises(ValueError, match="valid: scored-rounds, rounds-10"):
        parse_runs(["planet-boxing-value:nope"], [0])
    assert parse_runs(["planet-freeway-value:horizon-12"], [0]) == [SweepRun("planet-freeway-value", "horizon-12", 0)]
    with pytest.raises(ValueError, match="valid: default, td, horizon-12"):
        parse_runs(["planet-freeway-value:nope"], [0])


@pytest.mark.parametrize("argv, message", [
    (["nope", "--seeds", "0"], "unknown experiment 'nope'; valid: sokoban-wm"),
    (["boxing-wm", "--seeds", "3-1"], "the range 3-1 is empty"),
    (["boxing-wm", "--seeds", "x"], "'x' is not a seed or a range"),
    (["boxing-wm-alphazero:nope", "--seeds", "0"], "valid: unchanged, improved"),
    (["boxing-wm", "--seeds", "0", "--address", "127.0.0.1:1"], "no Ray cluster answers there"),
    (["boxing-wm", "--seeds", "0", "--address", "somewhere"], "expected auto, HOST:PORT"),
])
def test_bad_sweeps_stop_with_one_line_before_anything_starts(argv, message, capsys, tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    assert main(["sweep", *argv, "--profile", "smoke"]) == 2
    err = capsys.readouterr().err
    assert message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "results").exists() and not (tmp_path / "smoke").exists()


def test_a_local_ray_that_misses_its_startup_deadline_is_tried_again_then_refused_in_one_line(tmp_path, monkeypatch, capsys):
    import ray

    from wmthesis.sweep import RayStartFailed, start_ray

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    calls, shutdowns = [], []
    monkeypatch.setattr(ray, "is_initialized", lambda: False)
    monkeypatch.setattr(ray, "shutdown", lambda: shutdowns.append(1))

    def init(**kwargs):  # as Ray on a busy machine: the first two starts time out
        calls.append(kwargs)
        if len(calls) < 3:
            raise Exception("The current node timed out during startup.")

    monkeypatch.setattr(ray, "init", init)
    assert start_ray(None, cpus=2, attempts=3, wait_s=0) is True
    assert len(calls) == 3 and len(shutdowns) == 2 and calls[-1]["num_cpus"] == 2
    calls.clear()
    monkeypatch.setattr(ray, "init", lambda **kwargs: calls.append(kwargs) or (_ for _ in ()).throw(Exception("timed out")))
    with pytest.raises(RayStartFailed, match="did not start in 2 attempts"):
        start_ray(None, attempts=2, wait_s=0)
    assert len(calls) == 2
    monkeypatch.setattr("wmthesis.sweep.start_ray",
                        lambda *a, **k: (_ for _ in ()).throw(RayStartFailed("a local Ray did not start")))
    assert main(["sweep", "boxing-wm", "--seeds", "0", "--profile", "smoke"]) == 1
    assert capsys.readouterr().err.strip().splitlines()[-1] == "error: a local Ray did not start"


def _write_run(folder, experiment, seed, score, profile="quick", **extra):
    path = folder / "results" / experiment / f"{profile}-seed{seed}" / extra.get("variant", "") / "metrics.json"
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"experiment": experiment, "profile": profile, "seed": seed, "wall_seconds": 60.0 * seed,
                                "score": {"mean": score}, **extra}))
    return path


def test_the_summary_matches_a_hand_computation(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    for seed, score in enumerate([10.0, 14.0, 21.0]):  # seed 2 was resumed: its first run's time counts
        _write_run(tmp_path, "boxing-wm", seed, score, variant="separable-64",  # the default recipe
                   machine="vm (x86_64, 2 cores)", threads=2 if seed == 0 else 1,  # seeds 1, 2 on one core each
                   **({"first_run_wall_seconds": 3600.0} if seed == 2 else {}))
    _write_run(tmp_path, "planet-freeway", 0, 23.0, variant="freeway-tuned")
    value = _write_run(tmp_path, "planet-boxing-value", 4, 0.0)  # its headline is the value's score, not "score"
    value.write_text(json.dumps({**json.loads(value.read_text()), "value": {"mean": 26.8},
                                 "value_planner": {"full": {"mean": 31.5}}}))
    rows = write_summary()
    by_name = {row["experiment"]: row for row in rows}
    box = by_name["boxing-wm"]
    # by hand: mean 15, sample variance ((-5)^2 + (-1)^2 + 6^2) / 2 = 31, t_{0.975, 2} = 4.302652729911275
    assert (box["n"], box["mean"], box["seeds"]) == (3, 15.0, [0, 1, 2])
    assert box["std"] == pytest.approx(math.sqrt(31.0))
    half = 4.302652729911275 * math.sqrt(31.0) / math.sqrt(3)
    assert (box["ci_low"], box["ci_high"]) == (pytest.approx(15.0 - half), pytest.approx(15.0 + half))
    assert box["wall_seconds"] == [0.0, 60.0, 3600.0]
    one = by_name["planet-freeway"]
    assert (one["variant"], one["n"], one["mean"], one["std"], one["ci_low"]) == ("freeway-tuned", 1, 23.0, None, None)
    value_rows = {row["variant"]: row["mean"] for row in rows if row["experiment"] == "planet-boxing-value"}
    assert value_rows == {None: 26.8, "cem-with-value": 31.5}
    table = (tmp_path / "results" / "summary.md").read_text()
    assert "| boxing-wm | separable-64 | quick | 3 | 15.0 | 5.6 | [1.2, 28.8] | 0: 10.0, 1: 14.0, 2: 21.0 | 0, 1, 60 |" in table
    assert "Student-t" in table
    # the headline: the thesis's figure and the best published one, once, with its source as a footnote
    headline = table.split("## Every variant")[0]
    assert "| World Models on Boxing | 5.4.1 | above 18 on average across 5 runs | 15.0 [1.2, 28.8] (3 seeds) | above 18: " \
           "not settled at 3 seeds (the interval holds both the claim and its denial)" in headline
    assert "of one core | 93.5 (Simulus" in headline and "[^1]: leor-c/Simulus results/data/atari/Simulus.json" in headline
    assert "| World Models on Sokoban: % of levels its controller solves | 5.3 | 0 levels solved | not run yet |" in headline
    assert "| 02 | 0 with 2 threads, 1-60 with 1 (x86_64, 2 cores) |" in headline  # minutes a seed, by thread count
    csv_lines = (tmp_path / "results" / "summary.csv").read_text().splitlines()
    assert csv_lines[0].startswith("experiment,variant,profile,n,mean,std,ci_low,ci_high")
    assert csv_lines[1].startswith("boxing-wm,separable-64,quick,3,15.0,")
    assert json.loads((tmp_path / "results" / "summary.json").read_text())["rows"][0]["n"] == 3
    assert (tmp_path / "results" / "summary.png").stat().st_size > 5000
    assert aggregate([2.0, 2.0])["ci_low"] == 2.0  # no spread, no width
    near = aggregate([96.1, 90.3, 97.8], (0.0, 100.0))  # Boxoban medium's seeds: t reaches 104.5
    assert near["ci_high"] == 100.0 and near["ci_low"] == pytest.approx(aggregate([96.1, 90.3, 97.8])["ci_low"])


def test_the_ablations_are_paired_by_seed_against_the_headline_row(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    for seed, score in enumerate([10.0, 14.0, 21.0]):  # the first recipe, in the experiment's own folders
        _write_run(tmp_path, "boxing-wm", seed, score)
    for seed, score in [(1, 20.0), (2, 24.0), (3, 99.0), (10, 50.0)]:  # seed 3: no partner; 10 chose the recipe
        _write_run(tmp_path, "boxing-wm", seed, score, variant="separable-64")
    rows = write_summary()
    apart = [r for r in rows if r["variant"] == "separable-64, validation seeds"]
    assert [(r["seeds"], r["mean"]) for r in apart] == [([10], 50.0)]  # a row of its own, never a reported one
    (headline,) = [r for r in rows if (r["experiment"], r["variant"]) == ("boxing-wm", "separable-64")]
    assert headline["seeds"] == [1, 2, 3]  # the default's report seeds
    (ablation,) = ablation_rows(rows)
    assert (ablation["experiment"], ablation["variant"], ablation["against"]) == ("boxing-wm", None, "separable-64")
    assert (ablation["seeds"], ablation["mean"], ablation["default_mean"]) == ([1, 2], 17.5, 22.0)
    # by hand: differences -6 and -3, mean -4.5, sample std 2.1213, t_{0.975, 1} = 12.706204736
    half = 12.706204736174707 * math.sqrt(4.5) / math.sqrt(2)
    assert ablation["difference"] == -4.5
    assert (ablation["ci_low"], ablation["ci_high"]) == (pytest.approx(-4.5 - half), pytest.approx(-4.5 + half))
    table = (tmp_path / "results" / "summary.md").read_text()
    assert "| boxing-wm | population-16 (first recipe) | separable-64 | score | 1 2 | 17.5 | 22.0 | -4.5 [-23.6, +14.6] |" in table


def test_value_runs_are_paired_only_on_the_same_frozen_model(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))

    def value_run(seed, variant, cem, planet_mean):  # the thesis's CEM on the frozen model tells the model
        path = _write_run(tmp_path, "planet-boxing-value", seed, 0.0, variant=variant)
        path.write_text(json.dumps({**json.loads(path.read_text()), "value": {"mean": 20.0},
                                    "value_planner": {"full": {"mean": cem}},
                                    "planet": {"mean": planet_mean, "std": 5.0, "min": -9.0, "max": 9.0}}))

    for seed, cem in enumerate([10.0, 30.0, 40.0]):
        value_run(seed, "lean-value-rewards-0.7", cem, 3.3 if seed == 0 else 1.0)  # seed 0 on a model trained again
    for seed, cem in enumerate([50.0, 20.0, 36.0]):
        value_run(seed, "lean", cem, 1.0)
    for seed in range(3):
        value_run(seed, "rounds-10", 15.0, -2.9)  # every seed on another model
    rows = write_summary()
    lean, rounds = ablation_rows([r for r in rows if r["variant"] in
                                  ("lean-value-rewards-0.7, cem-with-value", "lean, cem-with-value",
                                   "rounds-10, cem-with-value")])
    assert (lean["variant"], lean["seeds"], lean["other_model"]) == ("lean", [1, 2], [0])
    assert (lean["mean"], lean["default_mean"], lean["difference"]) == (28.0, 35.0, -7.0)  # seed 0's +40 left out
    assert (rounds["seeds"], rounds["other_model"], rounds["difference"]) == ([], [0, 1, 2], None)
    assert (rounds["mean"], rounds["default_mean"]) == (15.0, pytest.approx(80.0 / 3))  # unpaired, over the same seeds
    table = (tmp_path / "results" / "summary.md").read_text()
    assert "| cem-with-value | 1 2 (0: another model, not paired) | 28.0 | 35.0 | -7.0 [" in table
    assert "| none (0 1 2: another model, not paired) | 15.0 | 26.7 | not paired |" in table


def test_seed_runs_reads_each_seeds_committed_run_of_a_variant(tmp_path, monkeypatch):
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    from wmthesis.experiments import seed_runs

    _write_run(tmp_path, "boxing-wm", 0, 10.0)  # the first recipe, in the experiment's own folders
    for seed in (1, 3):
        _write_run(tmp_path, "boxing-wm", seed, 30.0 + seed, variant="separable-64")
    _write_run(tmp_path, "sokoban-wm", 2, -5.0)
    assert {s: m["score"]["mean"] for s, m in seed_runs("boxing-wm", "quick", range(5)).items()} == {1: 31.0, 3: 33.0}
    told = []
    assert list(seed_runs("boxing-wm", "quick", range(3), "population-16", say=told.append)) == [0]
    assert told == ["no committed quick run of boxing-wm population-16 for seed(s) 1, 2: TRAIN = True, or "
                    "`python -m wmthesis reproduce boxing-wm --profile quick --seed 1 --variant population-16`"]
    assert list(seed_runs("sokoban-wm", "quick", (2, 4))) == [2] and seed_runs("boxing-wm", "thesis", (0,)) == {}
    with pytest.raises(ValueError, match="has no variants"):
        seed_runs("sokoban-wm", "quick", (2,), "nope")


def test_the_summary_aggregates_the_sokoban_agents_report_evaluations_over_seeds(tmp_path):
    for seed, (unfiltered, medium) in enumerate([(0.99, 0.86), (0.97, 0.80), (0.98, 0.83)]):
        folder = tmp_path / "results" / "sokoban-search" / f"quick-seed{seed}"
        folder.mkdir(parents=True)
        rows = {kind: {"solve_rate": rate, "levels": 1000, "seconds_per_level": 2.0}
                for kind, rate in (("unfiltered", unfiltered), ("medium", medium))}
        timed = {"training_wall_seconds": 600.0 * (seed + 1), "machine": "vm (x86_64, 2 cores)"} if seed < 2 else {}
        (folder / "boxoban-report-1000.json").write_text(json.dumps({"profile": "quick", "seed": seed, "levels": 1000,
                                                                    "rows": rows, **timed}))
    broken = tmp_path / "results" / "sokoban-search" / "quick-seed3" / "boxoban-report-1000.json"
    broken.parent.mkdir()
    broken.write_text(json.dumps({"profile": "quick", "seed": 3, "levels": 1000, "rows": ["unfiltered"]}))
    with pytest.warns(UserWarning, match="quick-seed3.*skipped"):
        rows = {row["variant"]: row for row in write_summary(tmp_path / "results")}
    medium = rows["boxoban-medium, 1000 report levels"]
    # by hand: mean 83, sample variance (3^2 + 3^2 + 0) / 2 = 9, t_{0.975, 2} = 4.302652729911275
    assert (medium["experiment"], medium["n"], medium["seeds"]) == ("sokoban-search", 3, [0, 1, 2])
    assert (medium["mean"], medium["std"]) == (pytest.approx(83.0), pytest.approx(3.0))
    assert medium["ci_high"] == pytest.approx(83.0 + 4.302652729911275 * 3.0 / math.sqrt(3))
    assert rows["boxoban-unfiltered, 1000 report levels"]["mean"] == pytest.approx(98.0)
    # a seed's minutes: its training, then that kind's levels one after another (1000 x 2 s); none
    # where the report predates the training time (seed 2)
    assert medium["wall_seconds"] == [2600.0, 3200.0, None]
    assert medium["machines"] == ["x86_64, 2 cores", "x86_64, 2 cores", None]


def test_a_run_called_again_keeps_the_wall_time_of_the_run_that_computed_it(tmp_path):
    path = tmp_path / "metrics.json"
    assert first_run_seconds(path, 21.9) == 21.9  # no earlier run
    path.write_text(json.dumps({"wall_seconds": 7200.0}))  # written before first_run_wall_seconds existed
    assert first_run_seconds(path, 21.9) == 7200.0
    path.write_text(json.dumps({"wall_seconds": 30.0, "first_run_wall_seconds": 5400.0, "curve": [1, 2]}))
    assert first_run_seconds(path, 21.9) == 5400.0
    assert first_run_seconds(path, 21.9, lambda earlier: earlier["curve"] == [1, 2]) == 5400.0  # the same training
    assert first_run_seconds(path, 21.9, lambda earlier: earlier["curve"] == [3]) == 21.9  # another: its time is not ours
    path.write_text("{not json")
    assert first_run_seconds(path, 21.9) == 21.9


def test_a_finished_run_asked_again_differs_only_in_when_where_and_how_long(tmp_path):
    from wmthesis.runs import unchanged_run

    path = tmp_path / "metrics.json"
    run = {"seed": 0, "date": "2026-11-27", "machine": "a", "threads": 2, "wall_seconds": 3600.0, "returns": [1.0, 2.0],
           "files": {"figures": ["x.png"]}}
    assert unchanged_run(path, run) is None  # nothing written yet
    path.write_text(json.dumps(run))
    again = {**run, "date": "2026-11-28", "machine": "b", "threads": 1, "wall_seconds": 3.1, "returns": (1.0, 2.0)}
    assert unchanged_run(path, {k: v for k, v in again.items() if k != "files"}) == run  # the earlier, as it was
    assert unchanged_run(path, {**again, "returns": [1.0, 3.0]}) is None  # another result: written again
    assert unchanged_run(path, {**again, "seed": 1}) is None
    path.write_text("{not json")
    assert unchanged_run(path, again) is None


def test_the_summary_skips_corrupt_and_foreign_files_naming_them(tmp_path):
    good = _write_run(tmp_path, "boxing-wm", 0, 5.0)
    corrupt = tmp_path / "results" / "boxing-wm" / "quick-seed1" / "metrics.json"
    corrupt.parent.mkdir(parents=True)
    corrupt.write_text('{"experiment": "boxing-wm", "profile": "qu')
    foreign = tmp_path / "results" / "other" / "metrics.json"
    foreign.parent.mkdir(parents=True)
    foreign.write_text(json.dumps({"loss": 0.1}))
    alien = _write_run(tmp_path, "someone-elses", 0, 1.0)
    not_a_number = tmp_path / "results" / "boxing-wm" / "quick-seed2" / "metrics.json"
    not_a_number.parent.mkdir(parents=True)
    not_a_number.write_text('{"experiment": "boxing-wm", "profile": "quick", "seed": 2, "score": {"mean": NaN}}')
    wrong_shape = tmp_path / "results" / "boxing-wm" / "quick-seed3" / "metrics.json"
    wrong_shape.parent.mkdir(parents=True)
    wrong_shape.write_text(json.dumps([{"experiment": "boxing-wm"}]))
    with pytest.warns(UserWarning) as caught:
        runs = read_runs(tmp_path / "results")
    assert [(r.experiment, r.seed, r.score, r.path) for r in runs] == [("boxing-wm", 0, 5.0, str(good))]
    warned = " ".join(str(w.message) for w in caught)
    assert all(f"{path}: skipped" in warned for path in (corrupt, foreign, alien, not_a_number, wrong_shape))
    assert f"{not_a_number}: skipped, not a run's metrics (TypeError: its score is nan, not a finite number)" in warned


# ---------------------------------------------------------------------------- on a local Ray
@pytest.fixture(scope="module")
def local_ray(tmp_path_factory):
    """One Ray of this machine's own for the module, its workers writing to a data folder of the module's."""
    import ray
    from ray import cloudpickle

    folder = tmp_path_factory.mktemp("sweep-data")
    before = os.environ.get("WMTHESIS_DATA")
    os.environ["WMTHESIS_DATA"] = str(folder)
    cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the test's runners travel to the workers
    assert start_ray(None, cpus=2)
    yield folder
    ray.shutdown()
    cloudpickle.unregister_pickle_by_value(sys.modules[__name__])
    os.environ.pop("WMTHESIS_DATA") if before is None else os.environ.update(WMTHESIS_DATA=before)


def test_a_smoke_sweep_runs_each_seed_as_a_task_and_resumes_with_nothing_to_do(local_ray, capsys):
    assert main(["sweep", "boxing-wm", "planet-freeway", "--seeds", "0-1", "--profile", "smoke"]) == 0
    out = capsys.readouterr().out
    assert out.count(": done (") == 4
    summary = json.loads((local_ray / "results" / "summary.json").read_text())
    rows = {(row["experiment"], row["variant"]): row for row in summary["rows"]}
    assert set(rows) == {("boxing-wm", "separable-64"), ("planet-freeway", "freeway-tuned")}
    for (experiment, variant), row in rows.items():
        assert row["n"] == 2 and row["seeds"] == [0, 1]
        files = [finished(SweepRun(experiment, variant, seed), "smoke") for seed in (0, 1)]
        scores = [json.loads(f.read_text())["score"]["mean"] for f in files]
        assert row["scores"] == scores and row["mean"] == pytest.approx(sum(scores) / 2)
    again = sweep(parse_runs(["boxing-wm", "planet-freeway"], [0, 1]), "smoke", runner=_must_not_run)
    assert {o["status"] for o in again.values()} == {"finished before"}


def _must_not_run(*args, **kwargs):
    raise AssertionError("a finished run ran again")


def _fails_on_seed_7(name, profile, seed, variant=None, progress=True):
    if seed == 7:
        raise RuntimeError("a deliberate fault in seed 7")
    return reproduce(name, profile, seed, variant=variant, progress=progress)


def test_a_run_that_raises_is_reported_and_the_others_finish(local_ray):
    outcome = sweep([SweepRun("planet-freeway", None, 7), SweepRun("planet-freeway", None, 8)], "smoke",
                    runner=_fails_on_seed_7, progress=False)
    failed, done = outcome[SweepRun("planet-freeway", None, 7)], outcome[SweepRun("planet-freeway", None, 8)]
    assert failed["status"] == "failed" and "RuntimeError: a deliberate fault in seed 7" in failed["error"]
    assert done["status"] == "done" and json.loads(open(done["path"]).read())["seed"] == 8
    assert finished(SweepRun("planet-freeway", None, 7), "smoke") is None


def _killed_once(name, profile, seed, variant=None, progress=True):
    """The first attempt kills its own worker (SIGKILL) once the vision has a checkpoint; a retry
    runs with random-rollout collection forbidden (its store must be kept, not collected again)."""
    import wmthesis.rollouts
    from wmthesis.utils import data_dir

    work = data_dir(profile, name, f"seed{seed}")
    log = data_dir() / "attempts.txt"
    attempts = log.read_text().split() if log.exists() else []
    log.write_text(" ".join([*attempts, "attempt"]))
    if not attempts:
        def kill_when_vision_checkpointed():
            while not (work / "vision.pt").exists():
                time.sleep(0.05)
            os.kill(os.getpid(), signal.SIGKILL)
        threading.Thread(target=kill_when_vision_checkpointed, daemon=True).start()
    else:
        rollouts = wmthesis.rollouts._rollouts

        def no_new_episodes(env_name, options, seed, todo, workers):
            assert len(todo) == 0, f"the retry collected {len(todo)} episodes again"
            return rollouts(env_name, options, seed, todo, workers)
        wmthesis.rollouts._rollouts = no_new_episodes
    return reproduce(name, profile, seed, variant=variant, progress=progress)


def test_a_killed_worker_is_retried_and_its_run_resumes(local_ray):
    run = SweepRun("boxing-wm", None, 5)
    outcome = sweep([run], "smoke", runner=_killed_once, progress=False)
    assert outcome[run]["status"] == "done", outcome[run]
    assert (local_ray / "attempts.txt").read_text().split() == ["attempt", "attempt"]
    assert json.loads(finished(run, "smoke").read_text())["seed"] == 5


def _records_order(name, profile, seed, variant=None, progress=True):
    """Notes when each run starts and ends; the prerequisite takes a while."""
    from wmthesis.utils import data_dir

    log = data_dir() / "order.txt"
    with open(log, "a") as f:
        f.write(f"start {name}\n")
    if name == "boxing-wm":
        time.sleep(3)
    if variant == "imitation":
        time.sleep(2)
    with open(log, "a") as f:
        f.write(f"end {name}{':' + variant if variant else ''}\n")
    return {"experiment": name, "profile": profile, "seed": seed, "variant": variant, "score": {"mean": 1.0},
            "scores": {f"AlphaZero {variant}": {"mean": 1.0}}, "variants": [variant]}


def test_a_run_waits_for_its_prerequisite_in_the_same_sweep(local_ray):
    runs = [SweepRun("boxing-wm-alphazero", "imitation", 11), SweepRun("boxing-wm", None, 11)]  # dependent first
    outcome = sweep(runs, "smoke", runner=_records_order, progress=False)
    assert {o["status"] for o in outcome.values()} == {"done"}
    assert (local_ray / "order.txt").read_text().split("\n")[:4] == [
        "start boxing-wm", "end boxing-wm", "start boxing-wm-alphazero", "end boxing-wm-alphazero:imitation"]


def test_variants_of_a_dependent_run_and_seed_go_one_after_the_other(local_ray):
    runs = [SweepRun("boxing-wm-alphazero", "imitation", 12), SweepRun("boxing-wm-alphazero", "unchanged", 12)]
    outcome = sweep(runs, "smoke", cpus=1, runner=_records_order, progress=False)  # two CPUs: room for both at once
    assert {o["status"] for o in outcome.values()} == {"done"}
    assert (local_ray / "order.txt").read_text().split("\n")[-5:-1] == [
        "start boxing-wm-alphazero", "end boxing-wm-alphazero:imitation",
        "start boxing-wm-alphazero", "end boxing-wm-alphazero:unchanged"]


def _sleeps(name, profile, seed, variant=None, progress=True):
    time.sleep(300)


def test_ctrl_c_stops_the_driver_and_its_runs_at_once(local_ray, capsys):
    """A Ctrl-C (SIGINT) to the driver while a run goes on cancels it and keeps nothing half-done."""
    import ray

    # A driver in a terminal raises KeyboardInterrupt on SIGINT. A suite started in the background
    # by a non-interactive shell (``pytest &`` in a script) inherits SIGINT ignored, and Python then
    # keeps SIG_IGN in every xdist worker from its start: the test sets the terminal's handler.
    found = signal.signal(signal.SIGINT, signal.default_int_handler)
    timer = threading.Timer(4.0, os.kill, (os.getpid(), signal.SIGINT))
    started = time.time()
    timer.start()
    try:
        with pytest.raises(KeyboardInterrupt):
            sweep([SweepRun("planet-freeway", None, 11)], "smoke", runner=_sleeps)
    finally:
        signal.signal(signal.SIGINT, found)
    assert time.time() - started < 30
    captured = capsys.readouterr()
    assert "interrupted: 0 runs kept, 1 stopped" in captured.out + captured.err
    assert finished(SweepRun("planet-freeway", None, 11), "smoke") is None
    assert ray.is_initialized()  # the fixture's Ray, not the sweep's own, stays up for the other tests


def test_a_port_that_answers_but_is_no_ray_cluster_is_one_line_within_the_timeout(monkeypatch, capsys, tmp_path):
    """A listening socket that is no Ray: the join is given up in a child process after the
    timeout, naming the address (ray.init would retry for minutes), by the library and the command."""
    import socket
    import time

    import pytest

    import wmthesis.sweep as sweep_module
    from wmthesis.__main__ import main
    from wmthesis.sweep import check_address, check_joinable

    with socket.socket() as server:
        server.bind(("127.0.0.1", 0))
        server.listen()
        address = f"127.0.0.1:{server.getsockname()[1]}"
        check_address(address)  # the port answers
        started = time.perf_counter()
        with pytest.raises(ValueError, match=f"--address '{address}': no Ray cluster could be joined there") as raised:
            check_joinable(address, timeout=8)
        assert time.perf_counter() - started < 20 and "\n" not in str(raised.value)
        monkeypatch.setattr(sweep_module, "JOIN_TIMEOUT_S", 8.0)  # the command's 30 s, shortened
        import ray

        monkeypatch.setattr(ray, "is_initialized", lambda: False)  # this module's own Ray may be up already
        monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))  # no run finished before
        started = time.perf_counter()
        assert main(["sweep", "boxing-wm", "--seeds", "0", "--profile", "smoke", "--address", address]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1].startswith(f"error: --address '{address}': no Ray cluster could be joined there"), err
        assert time.perf_counter() - started < 20


# ------------------------------------------------------------- an experiment of one's own
TOY_RECIPE = '''"""A toy experiment: its score is the seed plus a half."""
from wmthesis.runs import results_folder, run_header, write_json


def toy(profile, seed, variant, progress):
    metrics = {**run_header("toy", profile, seed, 0.0), "score": {"mean": seed + 0.5}}
    write_json(results_folder("toy", profile, seed) / "metrics.json", metrics)
    return metrics
'''


def _toy_declared(folder: str):
    """The toy declared in this process (a Ray worker starts without it)."""
    from wmthesis.declarations import DECLARED, Declaration, declare

    if folder not in sys.path:
        sys.path.insert(0, folder)
    return DECLARED.get("toy") or declare(Declaration("toy", "beyond", "toy_recipe:toy"))


def _toy_runner(folder, name, profile, seed, variant=None, progress=True):
    _toy_declared(folder)
    return reproduce(name, profile, seed, variant=variant, progress=progress)


def test_a_new_experiment_is_one_recipe_module_and_one_declaration(local_ray, tmp_path):
    """Declared from outside the package, a toy experiment runs through reproduce, a sweep on Ray
    and the summary, which read it like every other."""
    import functools

    from wmthesis.declarations import DECLARED, EXPERIMENTS, declare, Declaration
    from wmthesis.summary import summarise

    (tmp_path / "toy_recipe.py").write_text(TOY_RECIPE)
    try:
        _toy_declared(str(tmp_path))
        assert "toy" in EXPERIMENTS and EXPERIMENTS[-1] == "toy"
        with pytest.raises(ValueError, match="'toy' is declared already"):
            declare(Declaration("toy", "beyond", "toy_recipe:toy"))
        with pytest.raises(ValueError, match="builds on undeclared nowhere"):
            declare(Declaration("toy-2", "beyond", "toy_recipe:toy", builds_on=("nowhere",)))
        assert reproduce("toy", "smoke", 1)["score"]["mean"] == 1.5
        outcome = sweep([SweepRun("toy", None, 2), SweepRun("toy", None, 3)], "smoke", progress=False,
                        runner=functools.partial(_toy_runner, str(tmp_path)))
        assert [o["status"] for o in outcome.values()] == ["done", "done"]
        again = sweep([SweepRun("toy", None, 2)], "smoke", runner=_must_not_run, progress=False)
        assert [o["status"] for o in again.values()] == ["finished before"]
        runs = [r for r in read_runs(local_ray / "results") if r.experiment == "toy"]
        assert [(r.seed, r.score) for r in runs] == [(1, 1.5), (2, 2.5), (3, 3.5)]
        (row,) = [row for row in summarise(runs)]
        assert row["n"] == 3 and row["mean"] == pytest.approx(2.5)
    finally:
        DECLARED.pop("toy", None)
        sys.path.remove(str(tmp_path))
    assert "toy" not in EXPERIMENTS


def test_a_killed_driver_leaves_no_run_going_on(tmp_path):
    """A sweep's driver killed outright (SIGKILL: no Ctrl-C handler runs): the worker running its
    task ends within a few checks of the driver (the run resumes from its checkpoints next time)."""
    import subprocess

    pid_file = tmp_path / "worker.pid"
    code = (f"import os, time\nos.environ['WMTHESIS_DATA'] = {str(tmp_path)!r}\n"
            "from wmthesis.sweep import SweepRun, sweep\n"
            "def sleeps(name, profile, seed, variant=None, progress=True):\n"
            f"    open({str(pid_file)!r}, 'w').write(str(os.getpid()))\n"
            "    time.sleep(300)\n"
            "sweep([SweepRun('planet-freeway', None, 11)], 'smoke', runner=sleeps, progress=False)\n")
    driver = subprocess.Popen([sys.executable, "-c", code], start_new_session=True,
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    worker = None
    try:
        deadline = time.time() + 120
        while worker is None and time.time() < deadline and driver.poll() is None:
            time.sleep(0.5)
            if pid_file.is_file() and pid_file.read_text():
                worker = int(pid_file.read_text())
        assert worker is not None, "the task never started"
        driver.kill()
        driver.wait()
        deadline = time.time() + 30
        while _running(worker) and time.time() < deadline:
            time.sleep(0.5)
        assert not _running(worker), "the worker outlived its driver"
    finally:
        if worker is not None and _running(worker):
            os.kill(worker, signal.SIGKILL)
        try:
            os.killpg(driver.pid, signal.SIGKILL)  # Ray's own processes of the driver's session
        except ProcessLookupError:
            pass


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False

