"""Issue 31 on Freeway: the value starts from the PlaNet agent's own episodes, fits the
discounted sum of a long window of rewards, and is compared with the thesis's CEM and random
play on the same episodes; a re-run computes nothing again."""
import numpy as np
import pytest

from wmthesis.data import EpisodeStore

pytestmark = pytest.mark.usefixtures("one_torch_thread")  # see conftest.py


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """The default run (PlaNet on Freeway and its value, smoke, seed 0), trained once for the module."""
    import torch

    from wmthesis.experiments import reproduce

    folder, threads = tmp_path_factory.mktemp("freeway-value"), torch.get_num_threads()
    torch.set_num_threads(1)
    with pytest.MonkeyPatch.context() as patch:
        patch.setenv("WMTHESIS_DATA", str(folder))
        reproduce("planet-freeway-value", "smoke", 0, progress=False)
    torch.set_num_threads(threads)
    return folder


@pytest.fixture
def default_run(trained, tmp_path, monkeypatch):
    """A copy of the module's default run (files and their times) as this test's data folder."""
    import shutil

    shutil.copytree(trained, tmp_path, dirs_exist_ok=True)
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    return tmp_path


def test_freeway_value_starts_from_planets_episodes_and_compares_on_the_same_episodes(default_run):
    from wmthesis.experiments import reproduce
    from wmthesis.config import for_profile
    from wmthesis.experiments.planet_freeway_value import FREEWAY_VALUE
    from wmthesis.value.config import ValueEvaluationConfig
    from wmthesis.summary import run_scores
    from wmthesis.value.play import evaluation_seeds

    tmp_path = default_run
    metrics = reproduce("planet-freeway-value", "smoke", 0, progress=False)
    planet_run, work = tmp_path / "smoke" / "planet-freeway" / "freeway-tuned-seed0", tmp_path / "smoke" / "planet-freeway-value" / "seed0"
    with EpisodeStore(planet_run / "episodes.h5") as planet, EpisodeStore(work / "episodes.h5") as value:
        first = len(planet)
        assert len(value) == first + metrics["curve"][-1]["episodes"]  # the agent's episodes, then its own
        for i in (0, first - 1):
            assert np.array_equal(planet.episode(i)["actions"], value.episode(i)["actions"])
    config = metrics["config"]
    assert config["random_bouts"] == first and {k: config[k] for k in FREEWAY_VALUE} == FREEWAY_VALUE
    assert metrics["value_planner"]["config"]["discount"] == FREEWAY_VALUE["discount"]  # discounted as its targets
    bouts = [list(evaluation_seeds(0, k)) for k in range(for_profile(ValueEvaluationConfig, "smoke").freeway_episodes)]
    assert metrics["bouts"] == bouts and len(metrics["value_planner"]["returns"]) == len(bouts)
    assert metrics["random"]["episodes"] == metrics["planet"]["episodes"] == len(bouts)
    assert set(run_scores(metrics)) == {None, "cem-with-value"}
    cached = {p.name: p.stat().st_mtime_ns for p in work.glob("*.json")}
    again = reproduce("planet-freeway-value", "smoke", 0, progress=False)  # resumes: nothing played again
    assert {p.name: p.stat().st_mtime_ns for p in work.glob("*.json")} == cached
    assert again["value_planner"] == metrics["value_planner"] and again["curve"] == metrics["curve"]
    # the baselines' episodes are saved as each ends: cut off after them, none is played again
    (work / "baselines.json").unlink()
    played = (work / "baseline-bouts.json").stat().st_mtime_ns
    assert reproduce("planet-freeway-value", "smoke", 0, progress=False)["planet"] == metrics["planet"]
    assert (work / "baseline-bouts.json").stat().st_mtime_ns == played


def test_always_up_is_added_to_a_run_saved_without_it_playing_only_its_own_episodes(default_run):
    import json

    from wmthesis.experiments import reproduce
    from wmthesis.experiments.planet_freeway_value import BASELINES

    tmp_path = default_run
    metrics = reproduce("planet-freeway-value", "smoke", 0, progress=False)
    assert set(metrics["baselines"]) == set(BASELINES)
    up = metrics["baselines"]["always-up"]
    assert up["full"]["episodes"] == 2 and up["full"]["std"] == 0.0  # one action, one game: the same episode
    work = tmp_path / "smoke" / "planet-freeway-value" / "seed0"
    # a run saved before the row existed: its baselines and their episodes lack it
    saved = json.loads((work / "baselines.json").read_text())
    del saved["scores"]["always-up"]
    (work / "baselines.json").write_text(json.dumps(saved))
    bouts = json.loads((work / "baseline-bouts.json").read_text())
    kept = {i: {**p, "steps": -1} for i, p in bouts["plays"].items() if int(i) < 4}  # CEM's two, random's two, marked
    (work / "baseline-bouts.json").write_text(json.dumps({**bouts, "plays": kept}))
    again = reproduce("planet-freeway-value", "smoke", 0, progress=False)
    plays = json.loads((work / "baseline-bouts.json").read_text())["plays"]
    assert sorted(plays, key=int) == [str(i) for i in range(6)]
    assert [plays[str(i)]["steps"] for i in range(4)] == [-1] * 4  # kept, not played again
    assert again["baselines"] == metrics["baselines"] and again["planet"] == metrics["planet"]


def test_a_planner_variant_keeps_the_defaults_value_and_episodes_and_a_value_variant_fits_its_own(default_run):
    import json

    from wmthesis.experiments import reproduce
    from wmthesis.value.variants import FREEWAY_VALUE_VARIANTS as VALUE_VARIANTS
    from wmthesis.summary import run_scores

    tmp_path = default_run
    with pytest.raises(ValueError, match="valid: default, td, horizon-12, freeway-adam, adam-td"):
        reproduce("planet-freeway-value", "smoke", 0, variant="nope", progress=False)
    default = reproduce("planet-freeway-value", "smoke", 0, progress=False)
    longer = reproduce("planet-freeway-value", "smoke", 0, variant="horizon-12", progress=False)
    assert longer["value_planner"]["config"]["horizon"] == 12 != default["value_planner"]["config"]["horizon"]
    assert longer["curve"] == default["curve"] and longer["best_round"] == default["best_round"]  # the same value
    assert longer["baselines"] == default["baselines"]
    work = tmp_path / "smoke" / "planet-freeway-value"
    saved = json.loads((work / "horizon-12-seed0" / "baseline-bouts.json").read_text())
    assert saved == json.loads((work / "seed0" / "baseline-bouts.json").read_text())  # copied, not played again
    td = reproduce("planet-freeway-value", "smoke", 0, variant="td", progress=False)
    assert {k: td["config"][k] for k in VALUE_VARIANTS["td"].changes["value"]} == VALUE_VARIANTS["td"].changes["value"]
    assert td["value_planner"]["config"]["discount"] == VALUE_VARIANTS["td"].changes["value"]["discount"]
    assert set(run_scores(td)) == {"td", "td, cem-with-value"}
    saved = json.loads((tmp_path / "results" / "planet-freeway-value" / "smoke-seed0" / "td" / "metrics.json").read_text())
    assert saved["variant"] == "td" and saved["value_planner"] == td["value_planner"]  # beside the default's, not over it
    # notebook 08's table: the baselines once, then each run's players, with what each adds over UP
    from wmthesis.experiments.planet_freeway_value import freeway_plan_choices, value_rows

    rows = value_rows({"default": default, "horizon-12": longer, "td": td})  # the default by its name, or None
    assert value_rows({None: default}) == rows[:5]
    assert [r[0] for r in rows] == ["PlaNet (CEM), H12 (thesis)", "random play", "UP at every step",
                                    "value alone (default)", "CEM, H2, with the value at its end (default)",
                                    "CEM, H12, with the value at its end (horizon-12)", "value alone (td)",
                                    "CEM, H2, with the value at its end (td)"]  # horizon-12 keeps the default's value
    up = default["baselines"]["always-up"]["returns"]
    assert rows[2][3] == "+0.0 ± 0.0" and rows[3][1] == f"{default['value']['mean']:.1f} ± {default['value']['std']:.1f}"
    gain = np.mean(np.subtract(td["value_planner"]["returns"], up))
    assert rows[-1][3].startswith(f"{gain:+.1f} ± ")
    # where the td value changes the plan: its own planner (discounted at 0.99), on its own last episode
    compared = freeway_plan_choices("smoke", 0, "td", progress=False)
    assert compared["action_names"] == ["NOOP", "UP", "DOWN"] and compared["steps"] == 5
    assert all(len(c) == 5 and set(c) <= {0, 1, 2} for c in compared["choices"].values())
    key = json.loads((work / "td-seed0" / "plan_choices.json").read_text())["key"]
    assert key["planner"]["discount"] == 0.99 and key["round"] == td["best_round"]
    assert not (work / "seed0" / "plan_choices.json").exists()  # the default's folder is left alone


def test_open_loop_check_scores_the_frozen_model_on_moving_pixels_against_both_baselines(default_run):
    import json

    from wmthesis.planet.study import study_sizes
    from wmthesis.experiments.planet_freeway_value import open_loop_check

    tmp_path = default_run
    check = open_loop_check("smoke", 0, progress=False)
    horizon = study_sizes("smoke")["horizon"]
    assert all(len(check["errors"][name]) == horizon for name in ("model", "repeat last", "mean frame"))
    assert check["free_nats"] == 3.0 and check["kl_scale"] == 8e-3  # freeway-tuned's model
    assert check["below_mean_frame"] == [h for h in range(1, horizon + 1)
                                         if check["errors"]["model"][h - 1] < check["errors"]["mean frame"][h - 1]]
    assert check["diagnostics"]["kl"] >= 0
    assert all(len(check["filtered"][name]) == study_sizes("smoke")["context"] for name in ("model", "mean frame"))
    saved = tmp_path / "results" / "planet-freeway-value" / "smoke-seed0" / "open_loop_check.json"
    stamp = saved.stat().st_mtime_ns
    assert open_loop_check("smoke", 0, progress=False)["errors"] == check["errors"] and saved.stat().st_mtime_ns == stamp
    assert json.loads(saved.read_text())["key"]["updates"] == check["updates"]


def test_a_model_variant_fits_its_value_on_that_model_and_plays_its_own_baselines(tmp_path, monkeypatch):
    import json

    import torch

    from wmthesis.experiments import reproduce
    from wmthesis.experiments.planet_freeway_value import model_variant, open_loop_check

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    assert model_variant(None) == model_variant("td") == "freeway-tuned" and model_variant("freeway-adam") == "freeway-adam"
    adam = reproduce("planet-freeway-value", "smoke", 0, variant="freeway-adam", progress=False)
    planet_run = tmp_path / "smoke" / "planet-freeway" / "freeway-adam-seed0"
    checkpoint = torch.load(planet_run / "checkpoint.pt", weights_only=False)
    assert checkpoint["config"]["adam_eps"] == 1e-8 == checkpoint["optimizer"]["param_groups"][0]["eps"]
    work = tmp_path / "smoke" / "planet-freeway-value" / "freeway-adam-seed0"
    assert json.loads((work / "baselines.json").read_text())["key"]["planet_run"] == str(planet_run)
    assert not (tmp_path / "smoke" / "planet-freeway-value" / "seed0").exists()  # nothing copied from the default
    tuned = tmp_path / "smoke" / "planet-freeway" / "freeway-tuned-seed0"  # the value's first data: its episodes
    with EpisodeStore(tuned / "episodes.h5") as first, EpisodeStore(work / "episodes.h5") as value:
        assert adam["config"]["random_bouts"] == len(first)
        assert all(np.array_equal(first.episode(i)["actions"], value.episode(i)["actions"]) for i in range(len(first)))
    assert adam["variant"] == "freeway-adam"
    check = open_loop_check("smoke", 0, progress=False, model="freeway-adam")
    saved = tmp_path / "results" / "planet-freeway-value" / "smoke-seed0" / "freeway-adam" / "open_loop_check.json"
    assert json.loads(saved.read_text())["score"]["errors"] == check["errors"]
    assert check["diagnostics"]["embedding_spread"] >= 0
    # a value variant on that model: its baselines copied from freeway-adam's run, its own td value
    from wmthesis.experiments.planet_freeway_value import base_variant, model_variant
    from wmthesis.value.variants import FREEWAY_VALUE_VARIANTS as VALUE_VARIANTS

    assert base_variant("adam-td") == base_variant("freeway-adam") == "freeway-adam" and base_variant("td") is None
    for name in VALUE_VARIANTS:  # a base plays its own baselines, on the same model
        assert model_variant(base_variant(name)) == model_variant(name) and base_variant(base_variant(name)) == base_variant(name)
    td = reproduce("planet-freeway-value", "smoke", 0, variant="adam-td", progress=False)
    other = tmp_path / "smoke" / "planet-freeway-value" / "adam-td-seed0"
    assert (other / "baseline-bouts.json").read_text() == (work / "baseline-bouts.json").read_text()
    assert td["baselines"] == adam["baselines"]
    assert {k: td["config"][k] for k in VALUE_VARIANTS["adam-td"].changes["value"]} == VALUE_VARIANTS["adam-td"].changes["value"]
    assert td["config"]["target"] != adam["config"]["target"]
    assert not (tmp_path / "smoke" / "planet-freeway-value" / "seed0").exists()  # never the blind model's run
    # a planner variant on that model: freeway-adam's value and baselines, its own horizon (declared here)
    import importlib

    from wmthesis.variants import Variant, Variants

    module = importlib.import_module("wmthesis.experiments.planet_freeway_value")
    planner_only = Variant("adam-horizon-12", "freeway-adam's value, 12 steps", dict(planner=dict(horizon=12)),
                           builds_on="freeway-adam")
    monkeypatch.setattr(module, "FREEWAY_VALUE_VARIANTS", Variants("planet-freeway-value", *VALUE_VARIANTS.values(), planner_only))
    longer = module.planet_freeway_value("smoke", 0, "adam-horizon-12", progress=False)
    assert longer["value_planner"]["config"]["horizon"] == 12 != adam["value_planner"]["config"]["horizon"]
    assert longer["curve"] == adam["curve"] and longer["best_round"] == adam["best_round"]  # the same value
    assert longer["baselines"] == adam["baselines"]
    # the planner levers on validation episodes, played once, in the folder of the run that fitted the value
    from wmthesis.experiments.planet_freeway_value import validate_planners
    from wmthesis.value.play import validation_seeds

    with pytest.raises(ValueError, match="unknown Freeway planner lever 'H99'; valid: H3, H12"):
        validate_planners("smoke", 0, levers=("H99",), progress=False, variant="freeway-adam")
    levers = validate_planners("smoke", 0, levers=("H3", "H12"), progress=False, variant="adam-horizon-12")
    assert levers["H12"]["config"]["horizon"] == 12 and levers["H3"]["config"] == adam["value_planner"]["config"]
    saved = work / "planner-validation" / "h12" / "scores.json"
    assert json.loads(saved.read_text())["key"]["bouts"] == [list(validation_seeds(0, 0))]  # not an evaluation episode
    stamp = saved.stat().st_mtime_ns
    assert validate_planners("smoke", 0, levers=("H12",), progress=False, variant="freeway-adam") == {"H12": levers["H12"]}
    assert saved.stat().st_mtime_ns == stamp  # read, not played again
    assert not (tmp_path / "smoke" / "planet-freeway-value" / "adam-horizon-12-seed0" / "planner-validation").exists()


def test_levers_and_their_validation_bouts_are_checked_before_anything_plays(tmp_path, monkeypatch):
    from wmthesis.experiments.planet_freeway_value import validate_planners
    from wmthesis.value.comparison import checked_levers

    choices = {"a": {}, "b": {}}
    assert checked_levers("lever", None, choices, None, 5) == (("a", "b"), 5)
    assert checked_levers("lever", ["b"], choices, 2, 5) == (("b",), 2)
    with pytest.raises(ValueError, match="unknown lever 'c'; valid: a, b"):
        checked_levers("lever", ("a", "c"), choices, None, 5)
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    with pytest.raises(ValueError, match="validation bouts must be >= 1, got 0"):
        validate_planners("smoke", 0, levers=("H3",), bouts=0, progress=False)
    assert not any(tmp_path.iterdir())  # refused before any run began


def test_lookahead_ceiling_plays_each_horizon_once_on_the_evaluation_episodes(tmp_path, monkeypatch):
    from wmthesis.planet.bouts import play_bout
    from wmthesis.config import for_profile
    from wmthesis.experiments.planet_freeway_value import GAME, UP, lookahead_ceiling
    from wmthesis.value.config import ValueEvaluationConfig
    from wmthesis.planet.profiles import planet_config
    from wmthesis.value.play import evaluation_seeds

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    with pytest.raises(ValueError, match=r"lookahead horizons must be positive integers, got \(3, 0\)"):
        lookahead_ceiling("smoke", 0, horizons=(3, 0), progress=False)
    scores = lookahead_ceiling("smoke", 0, horizons=(1, 3), progress=False)
    assert list(scores) == [1, 3] and all(len(s["returns"]) == for_profile(ValueEvaluationConfig, "smoke").lookahead_episodes for s in scores.values())
    up = play_bout(GAME, planet_config(GAME, "smoke"), None, *evaluation_seeds(0, 0), UP)
    assert scores[1]["returns"] == [up["return"]] and scores[1]["first_returns"] == [up["first"]]  # horizon 1 is UP
    saved = tmp_path / "results" / "planet-freeway-value" / "smoke-seed0" / "lookahead-bouts.json"
    played = saved.stat().st_mtime_ns
    assert lookahead_ceiling("smoke", 0, horizons=(1, 3), progress=False) == scores
    assert saved.stat().st_mtime_ns == played  # a finished ceiling plays nothing again


def test_when_to_wait_sets_each_planners_choices_beside_the_lookaheads_on_its_own_episode(tmp_path, monkeypatch, request):
    from wmthesis.envs.freeway import play_lookahead
    from wmthesis.experiments.planet_freeway_value import GAME, UP, when_to_wait
    from wmthesis.config import for_profile
    from wmthesis.value.config import ValueEvaluationConfig
    from wmthesis.planet.profiles import planet_config
    from wmthesis.planet.train import make_planet_env
    from wmthesis.value.play import evaluation_seeds
    from wmthesis.value.planner import PLANNERS

    empty = tmp_path / "empty"
    monkeypatch.setenv("WMTHESIS_DATA", str(empty))
    with pytest.raises(ValueError, match=r"lookahead horizons must be positive integers, got \(0,\)"):
        when_to_wait("smoke", 0, variant=None, horizon=0, progress=False)
    assert not (empty / "smoke").exists()  # refused before any model or value was trained
    tmp_path = request.getfixturevalue("default_run")
    found = when_to_wait("smoke", 0, variant=None, horizon=3, progress=False)
    env = make_planet_env(GAME, planet_config(GAME, "smoke"))
    lookahead = play_lookahead(env, 3, evaluation_seeds(0, 0)[0])["actions"][:for_profile(ValueEvaluationConfig, "smoke").plan_steps]
    assert found["choices"]["lookahead"] == lookahead.tolist() and found["steps"] == len(lookahead)
    assert found["waits"] == int((lookahead != UP).sum())
    assert set(found["planners"]) == set(PLANNERS)
    for name in PLANNERS:
        picks = np.asarray(found["choices"][name])
        assert found["planners"][name]["ups_kept"] == pytest.approx(np.mean(picks[lookahead == UP] == UP))
    cached = tmp_path / "results" / "planet-freeway-value" / "smoke-seed0" / "when_to_wait.json"
    written = cached.stat().st_mtime_ns
    assert when_to_wait("smoke", 0, variant=None, horizon=3, progress=False)["choices"] == found["choices"]
    assert cached.stat().st_mtime_ns == written  # cached: nothing planned again


def test_hold_back_shares_tell_a_planner_that_waits_with_the_lookahead_from_one_that_does_not():
    from scipy.stats import fisher_exact

    from wmthesis.experiments.planet_freeway_value import hold_back_shares

    lookahead = np.array([0] * 20 + [1] * 80)  # waits (NOOP) on 20 steps, goes on 80
    same = hold_back_shares(lookahead, np.where(lookahead == 0, 2, 1))  # DOWN is holding back too
    assert same["waits_kept"] == 1.0 and same["ups_kept"] == 1.0 and same["p"] < 1e-15
    blind = hold_back_shares(lookahead, np.tile([0, 1, 1, 1], 25))  # a quarter of each, whatever comes
    assert blind["waits_kept"] == 0.25 and blind["ups_kept"] == 0.75 and blind["odds_ratio"] == 1.0 and blind["p"] == 1.0
    picks = np.array([0] * 12 + [1] * 8 + [0] * 30 + [1] * 50)
    assert hold_back_shares(lookahead, picks)["p"] == pytest.approx(fisher_exact([[12, 8], [30, 50]]).pvalue)
    assert np.isnan(hold_back_shares(np.ones(5, int), np.zeros(5, int))["waits_kept"])  # no wait to keep
