"""The command line: collect and view a store; bad input gives a message and exit status 2."""
import pytest
from wmthesis.__main__ import main
from wmthesis.data import EpisodeStore
from wmthesis.sokoban_search.tables import boxoban_rows
from wmthesis.viz import recording_rows


def test_collect_then_view(tmp_path, capsys):
    store = tmp_path / "box.h5"
    assert main(["collect", "boxing", "--episodes", "2", "--max-steps", "30", "--workers", "1",
                 "--out", str(store), "--profile", "smoke"]) == 0
    with EpisodeStore(store) as s:
        assert len(s) == 2 and s.num_steps == 60 and s.attrs["preprocessing"] == "world_models"
    assert main(["view", str(store), "--episode", "1", "--out", str(tmp_path / "view")]) == 0
    assert "2 episodes" in capsys.readouterr().out
    assert (tmp_path / "view" / "episode1.png").stat().st_size > 1000
    assert recording_rows(tmp_path / "view" / "episode1.rrd")["/observation"] == 30


def test_bad_input_is_a_message_not_a_traceback(tmp_path, capsys):
    assert main(["view", str(tmp_path / "missing.h5")]) == 2
    assert "missing.h5: no such episode store" in capsys.readouterr().err
    assert main(["reproduce", "planet-boxing", "--variant", "nope", "--profile", "smoke"]) == 2
    assert "valid: unchanged, action-repeat" in capsys.readouterr().err


def test_solve_sokoban_refuses_the_held_out_boxoban_sets(capsys):
    assert main(["solve-sokoban", "boxoban-hard", "--profile", "smoke"]) == 2
    assert "kept for an external check" in capsys.readouterr().err


def test_validate_refuses_an_unknown_lever_before_any_runs_and_reports_each_lever(capsys, monkeypatch):
    called = []
    row = {"solved": 92, "levels": 100, "solve_rate": 0.92, "nodes_per_level": 7229.4, "seconds_per_level": 6.04}
    import importlib

    recipe = importlib.import_module("wmthesis.experiments.sokoban_search")  # the module, not its recipe function
    monkeypatch.setattr(recipe, "validate", lambda *args: called.append(args[:4]) or {"rows": {"unfiltered": row}})
    assert main(["validate", "sokoban-search", "baseline", "bigger-brain", "--profile", "smoke"]) == 2
    err = capsys.readouterr().err
    assert "unknown lever 'bigger-brain' of sokoban-search; valid: baseline;" in err and not called
    assert "docs/findings/sokoban-search.md" in err  # where a removed lever's numbers went
    assert main(["validate", "planet-boxing-value", "H2 from a zero mean", "--profile", "smoke"]) == 2
    err = capsys.readouterr().err
    assert "docs/findings/planet-boxing-value.md" in err  # a removed planner lever
    from wmthesis.validation import levers_of

    listed = err.split("valid: ", 1)[1].split(" (levers no longer", 1)[0].split("; ")  # names with commas in them
    assert listed == list(levers_of("planet-boxing-value").changes) and any("," in name for name in listed)
    assert main(["validate", "sokoban-search", "baseline", "prior-afterwards", "--profile", "smoke", "--count", "3",
                 "--seeds", "0-1"]) == 0
    assert called == [("baseline", "smoke", 0, 3), ("prior-afterwards", "smoke", 0, 3),
                      ("baseline", "smoke", 1, 3), ("prior-afterwards", "smoke", 1, 3)]
    out = capsys.readouterr().out
    assert "sokoban-search, seed 1" in out and "baseline: unfiltered 92/100 (92.0%), 7,229 nodes and 6.0 s a level" in out
    with pytest.raises(SystemExit) as refused:  # no levers: refused by the argument check
        main(["validate", "planet-boxing-agent", "x"])
    assert refused.value.code == 2
    monkeypatch.setattr("wmthesis.experiments.reproduce", lambda *args: called.append(args) or {
        "score": {"mean": 31.0, "std": 4.0, "episodes": 10}, "wall_seconds": 3000.0})
    assert main(["validate", "boxing-wm", "separable-64", "--seeds", "0", "--profile", "smoke"]) == 2
    assert "chosen on seeds 10, 11, 12, not 0" in capsys.readouterr().err  # a reported seed never chooses
    assert main(["validate", "boxing-wm", "separable-64", "--seeds", "10-11", "--profile", "smoke"]) == 0
    assert called[-2:] == [("boxing-wm", "smoke", 10, "separable-64", True), ("boxing-wm", "smoke", 11, "separable-64", True)]
    assert "separable-64: 31.0 ± 4.0 over 10 bouts, 50 min" in capsys.readouterr().out


def test_alphazero_experiment_is_on_the_command_line(capsys):
    assert main(["reproduce", "boxing-wm-alphazero", "--variant", "nope", "--profile", "smoke"]) == 2
    assert "valid: unchanged, improved" in capsys.readouterr().err


def test_sokoban_search_trains_then_solves_levels_from_a_text_file(tmp_path, capsys, monkeypatch):
    import json

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path / "data"))
    levels = tmp_path / "mine.txt"
    levels.write_text("; 0\n#######\n#@ $ .#\n#######\n\n; 1\n#####\n#@$.#\n#####\n")
    assert main(["solve-sokoban", str(levels), "--profile", "smoke", "--seed", "3"]) == 2
    assert "reproduce sokoban-search --profile smoke --seed 3` first" in capsys.readouterr().err
    assert main(["reproduce", "sokoban-search", "--profile", "smoke", "--seed", "3"]) == 0
    assert "unseen levels solved" in capsys.readouterr().out
    metrics = json.loads((tmp_path / "data/results/sokoban-search/smoke-seed3/metrics.json").read_text())
    trained = [h["variant"] for h in metrics["history"]["pixels"][1:]]  # the curriculum, our generator's 10x10 unplayed
    assert trained == ["sokoban-small", "boxoban-unfiltered-train", "boxoban-medium-train"]
    assert sorted(metrics["tables"]) == ["sokoban", "sokoban-small"]  # yet both of our variants are evaluated
    generated = metrics["tables"]["sokoban"]
    assert generated["agent, learned model (pixels)"]["levels"] == generated["random play"]["levels"] == 4
    assert generated["agent, true simulator (pixels)"]["levels"] == generated["A* (reference)"]["levels"] == 2
    for kind in ("unfiltered", "medium"):  # the first 2 levels of the report files, played in the real game
        table = metrics["boxoban"]["tables"][kind]
        for title in ("agent, learned model (pixels)", "agent, true simulator (pixels)"):
            row = table[title]
            assert row["levels"] == 2 and row["source"].startswith(f"boxoban-{kind}-valid:005-009")
            assert row["replayed"] == row["solved"] and len(row["failed_levels"]) == 2 - row["solved"]
        assert table["A* (reference)"]["solved"] == 2  # both first levels solve with the rules written in
        assert table["random play"]["levels"] == 2 and table["thesis"]["solve_rate"] is None  # it never played Boxoban
    assert generated["thesis"] == {"solve_rate": 0.0} and metrics["tables"]["sokoban-small"]["thesis"]["solve_rate"] is None
    rows = {row[0]: row for row in boxoban_rows(metrics)}
    assert rows["A* (reference)"][1:3] == ["100.0", "100.0"] and "2e9 env steps" in rows["DRC(3,3), model-free"]
    assert metrics["boxoban"]["splits"]["validation"]["medium"] == "boxoban-medium-valid:000-001"
    out = tmp_path / "results.json"
    assert main(["solve-sokoban", str(levels), "--profile", "smoke", "--seed", "3", "--out", str(out)]) == 0
    results = json.loads(out.read_text())
    assert [r["level"] for r in results] == [0, 1]
    assert all({"level", "solved", "steps", "actions", "expanded", "seconds"} <= set(r) and r["steps"] == len(r["actions"])
               for r in results)
    levels.write_text("#####\n#@$x#\n#####\n")
    assert main(["solve-sokoban", str(levels), "--profile", "smoke", "--seed", "3"]) == 2
    assert "level 0: row 2 column 4 holds 'x'" in capsys.readouterr().err
    # written again by a call that trains nothing: the time it states for a run from scratch counts the training's sittings
    (tmp_path / "data/results/sokoban-search/smoke-seed3/metrics.json").unlink()
    assert main(["reproduce", "sokoban-search", "--profile", "smoke", "--seed", "3"]) == 0
    again = json.loads((tmp_path / "data/results/sokoban-search/smoke-seed3/metrics.json").read_text())
    assert again["training_wall_seconds"] == metrics["training_wall_seconds"] > 0
    assert again["first_run_wall_seconds"] > again["wall_seconds"] + 0.5 * again["training_wall_seconds"]


def test_planet_boxing_study_then_agent_from_the_command_line(tmp_path, capsys, monkeypatch):
    import json

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path / "data"))
    assert main(["reproduce", "planet-boxing-study", "--profile", "smoke"]) == 0
    assert "beats both baselines" in capsys.readouterr().out
    study = json.loads((tmp_path / "data/results/planet-boxing-study/smoke-seed0/metrics.json").read_text())
    assert sorted(study["runs"]) == sorted(f"{v}-seed{s}" for v in ("unchanged", "kl-scale", "free-nats") for s in (0, 1))
    errors = study["runs"]["free-nats-seed0"]["errors"]
    assert len(errors["model"]) == 4 and errors["repeat last"][0] < errors["repeat last"][-1]  # the truth moves on
    assert recording_rows(study["files"]["recording"])["/truth"] == 8

    assert main(["reproduce", "planet-boxing-agent", "--profile", "smoke", "--variant", "x"]) == 2
    assert "has no variants" in capsys.readouterr().err
    assert main(["reproduce", "planet-boxing-agent", "--profile", "smoke"]) == 0
    assert "over 2 bouts" in capsys.readouterr().out
    agent = json.loads((tmp_path / "data/results/planet-boxing-agent/smoke-seed0/metrics.json").read_text())
    assert agent["updates"] > study["updates"] and agent["env_steps"] == 80
    assert agent["difference"]["difference"] == agent["agent"]["full"]["mean"] - agent["random"]["full"]["mean"]
    assert all(first == full for first, full in zip(agent["agent"]["first_returns"], agent["agent"]["returns"]))
    # an evaluation cut off plays only the bouts it had not finished: each is saved as it ends
    work, metrics = tmp_path / "data/smoke/planet-boxing-agent/seed0", tmp_path / "data/results/planet-boxing-agent/smoke-seed0/metrics.json"
    saved = json.loads((work / "evaluation-bouts.json").read_text())
    assert saved["key"]["updates"] == agent["updates"] and sorted(saved["plays"], key=int) == ["0", "1", "2", "3"]
    kept = {i: {**play, "steps": -1} for i, play in saved["plays"].items() if int(i) < 3}  # marked: not played again
    (work / "evaluation-bouts.json").write_text(json.dumps({**saved, "plays": kept}))
    metrics.unlink()
    assert main(["reproduce", "planet-boxing-agent", "--profile", "smoke"]) == 0
    capsys.readouterr()
    plays = json.loads((work / "evaluation-bouts.json").read_text())["plays"]
    assert [plays[str(i)]["steps"] for i in range(4)] == [-1, -1, -1, saved["plays"]["3"]["steps"]]
    again = json.loads(metrics.read_text())
    assert again["agent"] == agent["agent"] and again["random"] == agent["random"]
    # metrics of another training of the same length (a retrained model) are not taken for this one's
    metrics.write_text(json.dumps({**again, "curve": {"test": []}, "agent": {**again["agent"], "full": "stale"}}))
    assert main(["reproduce", "planet-boxing-agent", "--profile", "smoke"]) == 0
    capsys.readouterr()
    fresh = json.loads(metrics.read_text())
    assert fresh == {**again, "wall_seconds": fresh["wall_seconds"], "date": fresh["date"]}

    assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", "scored-rounds"]) == 0  # the agent's model, frozen
    assert "PlaNet's CEM" in capsys.readouterr().out
    value = json.loads((tmp_path / "data/results/planet-boxing-value/smoke-seed0/metrics.json").read_text())
    assert [c["round"] for c in value["curve"]] == [0, 1] and value["curve"][1]["episodes"] == 1
    chosen = max(value["curve"], key=lambda c: (c["validation_mean"], -c["round"]))  # validation, not test
    assert value["best_round"] == chosen["round"] and len(value["returns"]) == 2
    assert value["returns"] == chosen["returns"] and len(chosen["validation"]) == 1
    assert value["difference"]["difference"] == value["value"]["mean"] - agent["random"]["full"]["mean"]
    planner = value["value_planner"]  # CEM with the chosen value at its end, on the same 2 bouts
    assert planner["config"]["horizon"] == 2 and len(planner["returns"]) == 2
    assert planner["full"]["mean"] == sum(planner["returns"]) / 2 and planner["first_returns"] == planner["returns"]
    assert value["value_first"]["mean"] == value["value"]["mean"]  # smoke bouts are shorter than 500 steps
    with EpisodeStore(tmp_path / "data/smoke/planet-boxing-value/seed0/episodes.h5") as own:
        assert len(own) == 3 and own.num_steps == 48  # 2 random bouts, 1 of its own, 16 steps each in smoke

    from wmthesis.experiments.planet_boxing_value import value_plan_choices

    compared = value_plan_choices("smoke", 0, progress=False, variant="scored-rounds")  # the last own bout's first 5 steps
    assert compared["steps"] == 5 and set(compared["choices"]) == {"CEM (thesis)", "CEM with value", "value alone"}
    assert all(len(c) == 5 and max(c) < 18 for c in compared["choices"].values()) and len(compared["action_names"]) == 18
    same = compared["agreement"]["CEM (thesis) = CEM with value"]
    thesis, ours = compared["choices"]["CEM (thesis)"], compared["choices"]["CEM with value"]
    assert same == sum(a == b for a, b in zip(thesis, ours)) / 5
    assert value_plan_choices("smoke", 0, progress=False, variant="scored-rounds")["choices"] == compared["choices"]  # cached, or the same again

    from wmthesis.experiments.planet_boxing_value import validate_agents
    from wmthesis.planet.train import load_planet, make_planet_env
    from wmthesis.value.rounds import load_value
    from wmthesis.value.play import play_value, validation_seeds

    agents = validate_agents("smoke", 0, "scored-rounds", ("round chosen on validation", "mean of the last 3"), 1,
                             progress=False)
    assert agents["round chosen on validation"]["rounds"] == [value["best_round"]]
    assert agents["mean of the last 3"]["rounds"] == [0, 1]  # only 2 rounds in smoke
    model, planet, _ = load_planet(tmp_path / "data/smoke/planet-boxing-agent/seed0")
    env = make_planet_env("boxing", planet)  # the bout after the one that chose the round, by the chosen value
    bout = play_value(env, model, load_value(tmp_path / "data/smoke/planet-boxing-value/seed0", model), planet.bits,
                      *validation_seeds(0, 1))["rewards"]
    env.close()
    assert agents["round chosen on validation"]["returns"] == [float(bout.sum())]

    from wmthesis.summary import run_scores

    assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", "rounds-10"]) == 0  # same model
    ten = json.loads((tmp_path / "data/results/planet-boxing-value/smoke-seed0/rounds-10/metrics.json").read_text())
    assert ten["variant"] == "rounds-10" and ten["config"]["rounds"] == 10
    assert ten["bouts"] == value["bouts"] and ten["planet"] == value["planet"]  # the same bouts and CEM on the same model
    assert set(run_scores(ten)) == {"rounds-10", "rounds-10, cem-with-value"} and set(run_scores(value)) == {None, "cem-with-value"}
    for removed in ("nope", "td"):  # unknown, or gone to the findings
        assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", removed]) == 2
        err = capsys.readouterr().err
        assert "valid: scored-rounds, rounds-10" in err and "docs/findings/planet-boxing-value.md" in err
    # the mean of the last rounds' values: from a copy of rounds-10's run, its rounds not fitted again
    results = tmp_path / "data/results/planet-boxing-value/smoke-seed0"
    assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", "rounds-10"]) == 0
    assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", "rounds-10-mean-3"]) == 0
    assert "the mean of the values of rounds 8-10" in capsys.readouterr().out
    ten, mean = (json.loads((results / v / "metrics.json").read_text()) for v in ("rounds-10", "rounds-10-mean-3"))
    assert mean["curve"] == ten["curve"] and len(ten["curve"]) == 11 and ten["agent_rounds"] == [ten["best_round"]]
    assert mean["agent_rounds"] == [8, 9, 10] and len(mean["returns"]) == 2 and mean["bouts"] == ten["bouts"]
    assert set(run_scores(mean)) == {"rounds-10-mean-3", "rounds-10-mean-3, cem-with-value"}
    # lean: the same agent from scratch, its rounds fitted again without their greedy bouts
    assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", "lean"]) == 0
    lean = json.loads((results / "lean" / "metrics.json").read_text())
    assert [e["loss"] for e in lean["curve"]] == [e["loss"] for e in ten["curve"]]
    assert lean["returns"] == mean["returns"] and lean["value_planner"]["returns"] == mean["value_planner"]["returns"]
    assert lean["best_round"] is None and "validation" not in lean["curve"][-1]
    # lean-value-rewards-0.7: lean's value from a copy (no round fitted again) under the planner chosen
    # on validation bouts; its CEM bout is that planner's with lean's own value
    from wmthesis.value.config import ValuePlannerConfig
    from wmthesis.value.bouts import value_planner_bout

    assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", "lean-value-rewards-0.7"]) == 0
    rewarded = json.loads((results / "lean-value-rewards-0.7" / "metrics.json").read_text())
    assert rewarded["curve"] == lean["curve"] and rewarded["returns"] == lean["returns"]
    planner = rewarded["value_planner"]["config"]
    assert planner == {**lean["value_planner"]["config"], "rewards": "value", "discount": 0.7}
    bout = value_planner_bout(tmp_path / "data/smoke/planet-boxing-agent/seed0",
                              tmp_path / "data/smoke/planet-boxing-value/lean-seed0", ValuePlannerConfig(**planner),
                              *rewarded["bouts"][0])
    assert rewarded["value_planner"]["returns"][0] == bout["return"]
    # own-rewards: lean's value, CEM's imagined rewards from the reward head refit on the run's bouts;
    # the head is refit once in its folder, its bouts and its shipped agent plan with it
    import torch
    from wmthesis.value.own_rewards import OWN_REWARDS
    from wmthesis.value.shipped import load_value_agent

    assert main(["reproduce", "planet-boxing-value", "--profile", "smoke", "--variant", "own-rewards"]) == 0
    own = json.loads((results / "own-rewards" / "metrics.json").read_text())
    assert own["curve"] == lean["curve"] and own["value_planner"]["config"] == {**lean["value_planner"]["config"],
                                                                                "reward_head": "own"}
    folder = tmp_path / "data/smoke/planet-boxing-value/own-rewards-seed0"
    head = torch.load(folder / OWN_REWARDS, weights_only=True)
    assert head["bouts"] > 0 and head["fit"]["after"] < head["fit"]["before"]
    bout = value_planner_bout(tmp_path / "data/smoke/planet-boxing-agent/seed0", folder,
                              ValuePlannerConfig(**own["value_planner"]["config"]), *own["bouts"][0])
    assert own["value_planner"]["returns"][0] == bout["return"]
    shipped = load_value_agent(folder / "agent.pt").model.reward_net.state_dict()
    assert all(torch.equal(shipped[k], v) for k, v in head["state"].items())
    # the planner's levers on the lean value's validation bouts, cached in its folder
    from wmthesis.value import bouts as value_bouts
    from wmthesis.experiments.planet_boxing_value import validate_planners
    from wmthesis.value.comparison import slug

    levers = ("value seeds CEM", "the value's rewards, discount 0.7")
    finished = [results / "lean" / "metrics.json", tmp_path / "data/smoke/planet-boxing-value/lean-seed0/agent.pt"]
    before = [(path.read_bytes(), path.stat().st_mtime_ns) for path in finished]
    checked = validate_planners("smoke", 0, levers=levers, variant="lean", progress=False)
    assert [(path.read_bytes(), path.stat().st_mtime_ns) for path in finished] == before  # read, not written again
    assert checked["the value's rewards, discount 0.7"]["config"]["rewards"] == "value" and checked[levers[0]]["config"]["rewards"] != "value"
    assert all(len(scores["returns"]) == 1 for scores in checked.values())
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(value_bouts, "value_planner_bout", lambda *a: pytest.fail("a cached lever was played again"))
        assert validate_planners("smoke", 0, levers=levers, variant="lean", progress=False) == checked
    # a variant that changes the planner alone plays its levers in its own folder, on its copy of lean's value
    copied = validate_planners("smoke", 0, levers=levers, variant="lean-value-rewards-0.7", progress=False)
    assert {k: v["returns"] for k, v in copied.items()} == {k: v["returns"] for k, v in checked.items()}
    own = tmp_path / "data/smoke/planet-boxing-value/lean-value-rewards-0.7-seed0/planner-validation"
    assert sorted(p.name for p in own.iterdir()) == sorted(slug(lever) for lever in levers)
    # the command line's validate: the same levers, one more played and saved where validate_planners finds it
    from wmthesis.value.variants import BOXING_PLANNER_LEVERS as PLANNER_LEVERS
    from wmthesis.value.tables import planner_lever_rows

    capsys.readouterr()
    assert main(["validate", "planet-boxing-value", *levers, "H1: the value agent", "--variant", "lean",
                 "--profile", "smoke", "--workers", "2"]) == 0
    printed = capsys.readouterr().out
    played = validate_planners("smoke", 0, levers=(*levers, "H1: the value agent"), variant="lean", progress=False)
    assert played["H1: the value agent"]["config"]["horizon"] == 1
    assert printed.split("lean's value\n")[1].splitlines() == [" | ".join(row) for row in planner_lever_rows(played, PLANNER_LEVERS)]
    # where the lean value changes the plan: from one belief per step, cached for its rounds
    from wmthesis.experiments.planet_boxing_value import value_plan_choices

    compared = value_plan_choices("smoke", 0, progress=False, variant="lean")
    assert compared["steps"] == 5 and all(len(c) == 5 for c in compared["choices"].values())
    cached = json.loads((tmp_path / "data/smoke/planet-boxing-value/lean-seed0/plan_choices.json").read_text())
    assert cached["key"]["round"] == [8, 9, 10] and cached["choices"] == compared["choices"]
