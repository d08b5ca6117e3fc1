"""Bad input never acts silently: each row of the "what happens when ..." table (docs/reference.md) is a
test here (or names the test that covers it)."""
import os
import re
import subprocess
import sys
import time

import numpy as np
import pytest
import torch

from wmthesis.__main__ import main
from wmthesis.envs import make_env
from wmthesis.envs.sokoban import SokobanEnv
from wmthesis.runs import FolderHeld, LOCK_NAME, hold, release, releasing_holds
from wmthesis.training import NonFiniteLoss, gradient_step


# ----------------------------------------------------------------------------- actions
@pytest.mark.parametrize("action", [-1, 8, 2.7, float("nan"), "2", None, np.array([1, 2]), True])
def test_sokoban_refuses_an_illegal_action_naming_it_and_the_range(action):
    env = make_env("sokoban-small", observation="grid")
    env.reset(seed=0)
    board = env.unwrapped.board.copy()
    with pytest.raises(ValueError, match=r"action .* valid action is an integer in \[0, 7\]"):
        env.step(action)
    assert np.array_equal(env.unwrapped.board, board)  # nothing was played


def test_sokoban_takes_numpy_integers():
    env = make_env("sokoban-small", observation="grid")
    env.reset(seed=0)
    for action in (np.int64(3), np.array(2), 1):
        env.step(action)
    assert env.unwrapped.steps == 3


@pytest.mark.parametrize("action", [99, -1, 1.5])
def test_boxing_refuses_an_illegal_action(action):
    env = make_env("boxing")
    env.reset(seed=0)
    with pytest.raises(ValueError, match=rf"action {action!r} .*\[0, 17\]"):
        env.step(action)
    env.close()


@pytest.mark.parametrize("name", ["sokoban-small", "freeway"])
def test_stepping_before_reset_says_to_call_reset(name):
    env = make_env(name)
    with pytest.raises(RuntimeError, match=r"call reset\(\) first"):
        env.step(0)
    env.close()


@pytest.mark.parametrize("name", ["sokoban-small", "freeway"])
def test_stepping_after_the_episode_ended_is_refused_saying_why(name):
    env = make_env(name, max_steps=3)
    env.reset(seed=0)
    for _ in range(3):
        _, _, terminated, truncated, _ = env.step(0)
    assert terminated or truncated
    with pytest.raises(RuntimeError, match=r"after the episode ended.*call reset\(\)"):
        env.step(0)
    env.reset(seed=1)
    env.step(0)  # a new episode plays again
    env.close()


def test_impossible_sokoban_sizes_are_refused_at_construction():
    started = time.perf_counter()
    with pytest.raises(ValueError, match=r"5 boxes cannot fit a 3x3 room: its 1 inner cells"):
        SokobanEnv(dim_room=(3, 3), num_boxes=5)
    with pytest.raises(ValueError, match=r"3 boxes cannot fit a 4x4 room: its 4 inner cells .* \(5\)"):
        SokobanEnv(dim_room=(4, 4), num_boxes=3)
    assert time.perf_counter() - started < 1.0  # at once, not after 1,000 rooms
    SokobanEnv(dim_room=(4, 5), num_boxes=2).reset(seed=0)  # 6 inner cells: 2 boxes, the player, one free


# ----------------------------------------------------------------------------- command line
def test_zero_episodes_collects_nothing_and_says_so(tmp_path, capsys):
    out = tmp_path / "none.h5"
    assert main(["collect", "sokoban-small", "--episodes", "0", "--out", str(out)]) == 0
    assert "nothing to collect" in capsys.readouterr().out and not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["collect", "sokoban-small", "--workers", "0"], "--workers: 0 is out of range (valid: 1 or more)"),
    (["collect", "sokoban-small", "--episodes", "-3"], "--episodes: -3 is out of range (valid: 0 or more)"),
    (["collect", "sokoban-small", "--max-steps", "0"], "--max-steps: 0 is out of range (valid: 1 or more)"),
    (["collect", "sokoban-small", "--seed", "-1"], "--seed: -1 is out of range (valid: 0 to 2,147,483,647)"),
    (["collect", "sokoban-small", "--episodes", "two"], "--episodes: 'two' is not an integer"),
    (["reproduce", "planet-boxing", "--seed", "-2"], "--seed: -2 is out of range (valid: 0 to 2,147,483,647)"),
    (["search", "planet-boxing", "--trials", "0"], "--trials: 0 is out of range (valid: 1 or more)"),
    (["view", "x.h5", "--episode", "-1"], "--episode: -1 is out of range (valid: 0 or more)"),
])
def test_invalid_numbers_on_the_command_line_are_refused_with_the_range(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 2 and message in capsys.readouterr().err


# ----------------------------------------------------------------------------- NaN and inf
def test_the_guard_names_the_model_the_update_and_the_term_before_any_change():
    layer = torch.nn.Linear(3, 1)
    optimiser = torch.optim.SGD(layer.parameters(), lr=0.1)
    before = [p.detach().clone() for p in layer.parameters()]
    out = layer(torch.ones(1, 3)).sum().abs() + 1
    terms = {"loss": out * float("nan"), "kl": out * 0, "reward": out * float("inf")}
    with pytest.raises(NonFiniteLoss, match=r"vision: non-finite loss term loss = nan, reward = inf at update 7"):
        gradient_step("vision", 7, terms, optimiser, layer.parameters(), kept="kept at ck.pt")
    grad = torch.nn.Parameter(torch.zeros(3))
    with pytest.raises(NonFiniteLoss, match=r"memory: non-finite gradient norm \(inf\) at update 2.*kept at ck.pt"):
        gradient_step("memory", 2, {"loss": grad.sqrt().sum()}, torch.optim.SGD([grad], lr=0.1), [grad],
                      kept="kept at ck.pt")  # d sqrt(x) / dx at 0 is inf, the loss 0 is finite
    assert all(torch.equal(a, b) for a, b in zip(before, layer.parameters())) and torch.equal(grad, torch.zeros(3))


def test_the_alphazero_heads_and_the_reward_model_stop_on_nan():
    from wmthesis.alphazero.heads import AlphaZeroHeads, make_optimiser, train_round
    from wmthesis.alphazero.latent_mdp import RewardModel, train_reward_model
    from wmthesis.alphazero.replay import Game
    from wmthesis.alphazero.config import AlphaZeroConfig

    config = AlphaZeroConfig(epochs=1, batch_size=4)
    heads = AlphaZeroHeads(2, 3, 2)
    T = 6
    game = Game(index=0, features=np.full((T, 5), np.nan, np.float32), policies=np.full((T, 2), 0.5, np.float32),
                actions=np.zeros(T, np.int64), rewards=np.zeros(T, np.float32),
                predicted_rewards=np.zeros(T, np.float32), root_values=np.zeros(T, np.float32),
                depths=np.zeros(T, np.int16), q=np.zeros((T, 2), np.float32), terminated=True,
                last_features=np.zeros(5, np.float32), seconds=0.0)
    with pytest.raises(NonFiniteLoss, match="AlphaZero heads: non-finite loss term .* at update 1"):
        train_round(heads, make_optimiser(heads, config), [game], config, np.random.default_rng(0))
    model = RewardModel(5, 2, hidden=8, reward_range=1)
    rows = (np.ones((8, 5), np.float32), np.zeros(8, np.int64), np.zeros(8, np.float32))
    rows[0][3] = np.inf
    with pytest.raises(NonFiniteLoss, match="reward model: non-finite"):
        train_reward_model(model, torch.optim.Adam(model.parameters()), rows, 1, 4, np.random.default_rng(0))


# ----------------------------------------------------------------------------- held folders
HOLDER = """
import sys, time
from wmthesis.runs import hold
hold(sys.argv[1])
print("held", flush=True)
time.sleep(60)
"""


def test_a_folder_held_by_another_run_names_the_holder_and_a_dead_ones_lock_is_taken_over(tmp_path, capsys):
    folder = tmp_path / "run"
    other = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline().strip() == "held"
        with pytest.raises(FolderHeld, match=rf"held by another run: process {other.pid} \(.*-c"):
            hold(folder)
    finally:
        other.kill()
        other.wait()
    assert (folder / LOCK_NAME).exists()  # SIGKILL left its lock behind
    assert hold(folder) == folder.resolve()
    assert "taking over the lock of a run that is gone" in capsys.readouterr().err
    assert str(os.getpid()) in (folder / LOCK_NAME).read_text()
    hold(folder)  # the same process may hold it again
    release(folder)
    assert (folder / LOCK_NAME).exists()
    release(folder)
    assert not (folder / LOCK_NAME).exists()


def test_an_experiment_lets_go_of_its_folder_when_it_returns_or_fails(tmp_path):
    @releasing_holds
    def experiment(fail: bool):
        hold(tmp_path / "work")
        assert (tmp_path / "work" / LOCK_NAME).exists()
        if fail:
            raise KeyError("boom")

    experiment(False)
    assert not (tmp_path / "work" / LOCK_NAME).exists()
    with pytest.raises(KeyError):
        experiment(True)
    assert not (tmp_path / "work" / LOCK_NAME).exists()


def test_the_command_line_reports_a_held_folder_in_one_line(tmp_path, capsys, monkeypatch):
    import wmthesis.experiments as experiments

    def held(*args, **kwargs):
        raise FolderHeld("data/smoke/sokoban-wm/seed0 is held by another run: process 12 ('python -m wmthesis')")

    monkeypatch.setattr(experiments, "reproduce", held)
    assert main(["reproduce", "sokoban-wm", "--profile", "smoke"]) == 2
    assert "error: data/smoke/sokoban-wm/seed0 is held by another run: process 12" in capsys.readouterr().err


# ----------------------------------------------------------------------------- artifacts of the earlier layout
def test_a_controller_checkpoint_of_the_earlier_layout_is_read(tmp_path, monkeypatch):
    """``controller.pkl`` pickled the CMA-ES strategy with its ``SeededNormal`` under
    ``wmthesis.agents.controller_training``; it is found where it lives now."""
    import pickle
    import types

    from wmthesis.utils import read_pickle
    from wmthesis.world_models import evolution

    old = types.ModuleType("wmthesis.agents.controller_training")
    old.SeededNormal = evolution.SeededNormal
    monkeypatch.setitem(sys.modules, "wmthesis.agents.controller_training", old)
    monkeypatch.setattr(evolution.SeededNormal, "__module__", "wmthesis.agents.controller_training")
    normal = evolution.SeededNormal(3)
    (tmp_path / "controller.pkl").write_bytes(pickle.dumps({"randn": normal}))
    monkeypatch.undo()
    assert b"wmthesis.agents.controller_training" in (tmp_path / "controller.pkl").read_bytes()
    loaded = read_pickle(tmp_path / "controller.pkl")["randn"]
    assert isinstance(loaded, evolution.SeededNormal)
    assert np.array_equal(loaded(4), evolution.SeededNormal(3)(4))


WRITER = """
import sys, time
from wmthesis.data import EpisodeStore
store = EpisodeStore(sys.argv[1], "a", env="test", obs_shape=(2,))
print("open", flush=True)
time.sleep(60)
"""


def test_a_store_open_for_writing_in_another_process_is_named_as_such(tmp_path):
    from wmthesis.data import EpisodeStore, StoreError

    path = tmp_path / "busy.h5"
    other = subprocess.Popen([sys.executable, "-c", WRITER, str(path)], stdout=subprocess.PIPE, text=True)
    try:
        assert other.stdout.readline().strip() == "open"
        with pytest.raises(StoreError, match=r"busy.h5 is open for writing in another process"):
            EpisodeStore(path, "a")
    finally:
        other.kill()
        other.wait()


# ----------------------------------------------------------------------------- found when tried as a new user would
def test_a_levels_file_that_is_binary_or_a_folder_is_refused_naming_it(tmp_path, capsys):
    from wmthesis.__main__ import main

    binary = tmp_path / "levels.txt"
    binary.write_bytes(bytes(range(256)) * 4)
    assert main(["solve-sokoban", str(binary), "--profile", "smoke"]) == 2
    assert f"{binary} is not a text file of levels" in capsys.readouterr().err
    assert main(["solve-sokoban", str(tmp_path), "--profile", "smoke"]) == 2
    assert f"{tmp_path} is a folder, not a levels file" in capsys.readouterr().err


def test_a_store_that_cannot_be_created_or_read_says_which_and_what_to_do(tmp_path, capsys):
    from wmthesis.__main__ import main
    from wmthesis.data import EpisodeStore, StoreError
    from wmthesis.rollouts import collect

    blocker = tmp_path / "a-file"
    blocker.write_text("")
    assert main(["collect", "sokoban-small", "--episodes", "1", "--out", str(blocker / "s.h5"), "--profile", "smoke"]) == 2
    err = capsys.readouterr().err
    assert f"{blocker / 's.h5'}: cannot create its folder" in err and ".tmp" not in err
    store = collect("sokoban-small", 1, tmp_path / "cut.h5", progress=False)
    store.write_bytes(store.read_bytes()[:2000])  # truncated
    with pytest.raises(StoreError, match=r"cut\.h5: .*delete it and run again"):
        EpisodeStore(store)


@pytest.mark.parametrize("argv, says", [
    (["reproduce", "boxing-wm", "--seed", "abc"], "is not an integer"),
    (["reproduce", "boxing-wm", "--variant", "nope"], "unknown variant 'nope'"),
    (["reproduce", "planning-budget", "--variant", "x"], "has no variants"),
    (["validate", "boxing-wm", "bogus"], "unknown lever 'bogus'"),
    (["validate", "boxing-wm", "population-16", "--seeds", "0-1000"], "more than 100 seeds"),
    (["sweep", "boxing-wm", "--seeds", "0-1000000"], "more than 100 seeds"),
    (["sweep", "boxing-wm:nope", "--seeds", "0"], "unknown variant 'nope'"),
    (["budget-curve", "mcts", "--validation", "--search", "root=chess"], "unknown root 'chess'"),
    (["play", "boxing-wm", "--variant", "nope"], "unknown variant 'nope'"),
    (["reproduce", "sokoban-wm", "--seed", str(10**20)], "out of range (valid: 0 to 2,147,483,647)"),
    (["play", "boxing-wm", "--seed", "-1"], "out of range (valid: 0 to 2,147,483,647)"),
    (["summary", "--results", "/no/such/folder"], "--results /no/such/folder: no such folder"),
    (["validate", "planet-freeway-value", "nope"], "unknown lever 'nope' of planet-freeway-value"),
    (["validate", "planet-boxing-value", "nope"], "unknown lever 'nope' of planet-boxing-value"),
    (["validate", "sokoban-search", "nope"], "unknown lever 'nope' of sokoban-search"),
    (["reproduce", "planet-freeway-value", "--variant", "nope"], "unknown variant 'nope' of planet-freeway-value"),
    (["budget-curve", "mcts", "--budgets", "99999999999999999999"], "above the most one run takes (16,384)"),
    (["budget-curve", "cem", "--budgets", "6x1000000x3"], "above the most one run takes"),
    (["budget-curve", "mcts", "--validation", "--search", "c_scale=-1"], "c_scale='-1': it must be a finite number above 0"),
    (["budget-curve", "mcts", "--validation", "--search", "c_scale=nan"], "c_scale='nan': it must be a finite number"),
    (["budget-curve", "mcts", "--validation", "--search", "considered=2.5"], "considered='2.5' is not a whole number"),
])
def test_the_command_line_checks_its_arguments_before_torch_ray_or_ale_py_load(argv, says):
    import subprocess
    import sys

    code = ("import sys\nfrom wmthesis.__main__ import main\n"
            f"try:\n    code = main({argv!r})\nexcept SystemExit as e:\n    code = e.code\n"
            "print(code, sorted(m for m in ('torch', 'ray', 'ale_py', 'gymnasium') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert done.stdout.split() == ["2", "[]"] and says in done.stderr, (done.stdout, done.stderr)
    if argv[0] in ("validate", "summary"):  # our own refusals are one line (argparse's add its usage)
        assert done.stderr.count("\n") == 1, done.stderr


def test_ctrl_c_in_any_command_is_one_line_and_exit_status_130(monkeypatch, capsys):
    import wmthesis.__main__ as cli

    def interrupted(args):
        raise KeyboardInterrupt

    for command, name in ((["reproduce", "boxing-wm", "--profile", "smoke"], "cmd_reproduce"),
                          (["collect", "boxing", "--profile", "smoke"], "cmd_collect")):
        monkeypatch.setattr(cli, name, interrupted)
        assert cli.main(command) == 130
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"{command[0]} interrupted: what it finished is kept; run the same command again to resume"]


def test_a_seed_range_is_bounded_before_anything_counts_it_out():
    import time

    from wmthesis.sweep import MAX_SEED, parse_seeds

    start = time.perf_counter()
    with pytest.raises(ValueError, match="more than 100 seeds"):
        parse_seeds("0-1000000000")
    assert time.perf_counter() - start < 0.1  # refused, not enumerated
    with pytest.raises(ValueError, match="seeds are at most 2,147,483,647"):
        parse_seeds(str(10**20))
    assert parse_seeds(f"0-2,{MAX_SEED}") == [0, 1, 2, MAX_SEED]
    assert len(parse_seeds("0-99")) == 100


def test_a_storage_url_that_is_no_database_is_one_line(capsys, tmp_path):
    from wmthesis.__main__ import main

    assert main(["search", "planet-boxing", "--trials", "1", "--storage", "bogus://nowhere"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "name a database URL of sqlite://..., postgresql://..., mysql://..." in err[0]
    assert main(["search", "planet-boxing", "--trials", "1", "--storage", f"sqlite:///{tmp_path}/no/such/folder/x.db"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error: cannot open the optuna storage sqlite:///")


@pytest.mark.parametrize("actions, says", [([99, -1], "action 99 of game 0 is out of range"),
                                           ([0.5, 1.7], "are not integers"), ([1, 2, 3], "2 actions, got shape (3,)"),
                                           ([True, False], "are not integers")])
def test_a_batched_game_checks_its_actions_as_a_single_game_does(actions, says):
    from wmthesis.envs.vector import make_game

    for name in ("boxing", "sokoban-small"):
        game = make_game(name, 2)
        try:
            game.reset(np.array([0, 1]))
            with pytest.raises(ValueError, match=re.escape(says)) as refused:
                game.step(actions)
            assert "\n" not in str(refused.value)  # one line
            game.step(np.array([0, 1]))  # a good batch still plays
        finally:
            game.close()


def test_a_levels_file_that_is_no_text_and_help_are_answered_before_torch_loads(tmp_path):
    import subprocess
    import sys

    binary = tmp_path / "levels.txt"
    binary.write_bytes(bytes(range(256)))
    code = ("import sys\nfrom wmthesis.__main__ import main\n"
            f"code = main(['solve-sokoban', {str(binary)!r}, '--profile', 'smoke'])\n"
            "try:\n    main(['--help'])\nexcept SystemExit as e:\n    code = (code, e.code)\n"
            "print(code, sorted(m for m in ('torch', 'ray', 'ale_py') if m in sys.modules))")
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, timeout=60)
    assert done.stdout.splitlines()[-1] == "(2, 0) []", done.stdout
    assert done.stderr.count("\n") == 1 and f"{binary}" in done.stderr and "usage:" in done.stdout


def test_a_seed_out_of_range_is_refused_before_any_folder_is_made(tmp_path, monkeypatch):
    from wmthesis.experiments import reproduce

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    for seed, says in ((10**20, "seeds are from 0 to 2,147,483,647"), (-1, "seeds are from 0"),
                       (1.5, "a seed is an integer")):
        with pytest.raises(ValueError, match=says):
            reproduce("sokoban-wm", "smoke", seed, progress=False)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("url", ["postgresql://me:s3cr3t-pw@db.example:5432/studies",
                                 "mysql+pymysql://me:s3cr3t-pw@db.example/studies"])
def test_a_storage_password_never_appears_in_what_the_command_line_says(url, capsys):
    from wmthesis.__main__ import main
    from wmthesis.utils import masked, secret_free

    assert masked(url).count("***") == 1 and "s3cr3t-pw" not in masked(url)
    assert masked("sqlite:///data/search/x.db") == "sqlite:///data/search/x.db"
    assert "s3cr3t-pw" not in secret_free(f"could not connect to {url} (password s3cr3t-pw rejected)", url)
    main(["search", "planet-boxing", "--trials", "1", "--storage", url.replace("postgresql", "oracle").replace("mysql+pymysql", "oracle")])
    said = capsys.readouterr()
    assert "s3cr3t-pw" not in said.out + said.err and "me:***@db.example" in said.err


@pytest.mark.parametrize("bouts", [0, -1, 1001, 10**6, 2.5, True, "3"])
def test_a_count_of_bouts_is_bounded_before_any_game_is_built(bouts, monkeypatch):
    import time
    from pathlib import Path

    import wmthesis
    from wmthesis.play import play

    monkeypatch.setenv("WMTHESIS_DATA", str(Path(__file__).resolve().parents[1] / "data"))  # the shipped agent
    agent = wmthesis.load("boxing-wm")
    started = time.perf_counter()
    with pytest.raises(ValueError, match="must be a whole number from 1 to 1,000"):
        agent.play(bouts=bouts)
    with pytest.raises(ValueError, match="--bouts must be a whole number from 1 to 1,000"):
        play("boxing-wm", bouts=bouts)
    assert time.perf_counter() - started < 1.0  # refused at once, no game built


@pytest.mark.parametrize("games", [0, -2, 2.5, 5000])
def test_a_batched_game_refuses_a_count_it_cannot_build_before_the_emulator(games):
    from wmthesis.envs.vector import make_game

    with pytest.raises(ValueError, match=r"num_envs \(games played at once\) must be a whole number from 1 to 4,096"):
        make_game("boxing", games)


@pytest.mark.parametrize("seeds, says", [([3, -2], "seeds are from 0 to"), ([1.5, 2], "a seed is an integer"),
                                         ([1], "one seed per game: 2 games, 1 seeds")])
def test_a_batched_game_refuses_seeds_it_cannot_take(seeds, says):
    from wmthesis.envs.vector import make_game

    game = make_game("sokoban", 2)
    with pytest.raises(ValueError, match=says):
        game.reset(seeds)
    assert game.reset(np.array([3, 4])).shape[0] == 2  # numpy integers are seeds too


def test_an_empty_data_folder_setting_is_refused_not_read_as_the_current_folder(monkeypatch, tmp_path):
    from wmthesis.utils import data_dir

    monkeypatch.chdir(tmp_path)
    monkeypatch.setenv("WMTHESIS_DATA", " ")
    with pytest.raises(ValueError, match="WMTHESIS_DATA is set but empty"):
        data_dir("results")
    assert not any(tmp_path.iterdir())


@pytest.mark.parametrize("scored, asked, played", [(3, None, 3), (None, None, 10), (3, 2, 2), (40, None, 10)])
def test_play_plays_by_default_ten_bouts_or_every_scored_one_where_fewer(scored, asked, played, monkeypatch):
    import wmthesis.agents
    from wmthesis.play import play

    class Scored:
        variant, scored_bouts, experiment, profile, seed = "stand-in", scored, "boxing-wm", "quick", 0

        def play_bouts(self, bouts, on_bout=None):
            if scored is not None and bouts > scored:
                raise ValueError(f"scored on {scored} bouts, not {bouts}")
            return [{"bout": k, "return": 1.0, "steps": 1} for k in range(bouts)]

        def score_line(self, plays):
            return f"{len(plays)} bouts"

        def check_weights(self):
            pass

    monkeypatch.setattr(wmthesis.agents, "load", lambda *a, **k: Scored())
    lines = []
    play("boxing-wm", bouts=asked, on_play=lines.append)
    assert lines == [f"{played} bouts"]


def test_an_agents_dream_open_loop_and_replay_refuse_nan_frames_and_bad_actions_naming_the_range(monkeypatch):
    from pathlib import Path

    import wmthesis

    monkeypatch.setenv("WMTHESIS_DATA", str(Path(__file__).resolve().parents[1] / "data"))
    agent = wmthesis.load("boxing-wm")
    frames, actions = np.zeros((12, 64, 64, 3), np.uint8), np.zeros(12, np.int64)
    with pytest.raises(ValueError, match="frames are uint8 images"):
        agent.dream(np.full((12, 64, 64, 3), np.nan), actions, context=4, horizon=4)
    with pytest.raises(ValueError, match=r"not integers; a valid action is an integer in \[0, 17\]"):
        agent.dream(frames, actions + 0.5, context=4, horizon=4)
    with pytest.raises(ValueError, match=r"action 18 of game 3 is out of range; a valid action is an integer in \[0, 17\]"):
        agent.dream(frames, np.where(np.arange(12) == 3, 18, 0), context=4, horizon=4)
    assert agent.dream(frames, actions, context=4, horizon=4)["prediction"].shape == (4, 64, 64, 3)
    planet = wmthesis.load("planet-boxing-agent")
    size = planet.config.frame_size
    with pytest.raises(ValueError, match=r"not integers"):
        planet.open_loop(np.zeros((8, size, size, 3), np.uint8), np.full(8, 1.5), context=3)
    sokoban = wmthesis.load("sokoban-search")
    board = "#####\n#@$.#\n#####"
    with pytest.raises(ValueError, match=r"not integers; a valid action is an integer in \[0, 7\]"):
        sokoban.replay(board, [1.5])
    with pytest.raises(ValueError, match=r"action 9 of game 1 is out of range; a valid action is an integer in \[0, 7\]"):
        sokoban.replay(board, [3, 9])
    assert sokoban.replay(board, [])["frames"].shape[0] == 1


def test_play_plays_the_controller_as_changed_and_refuses_nan_weights_naming_the_part(monkeypatch):
    from pathlib import Path

    import torch

    import wmthesis

    monkeypatch.setenv("WMTHESIS_DATA", str(Path(__file__).resolve().parents[1] / "data"))
    agent = wmthesis.load("boxing-wm")
    scored = agent.play(bouts=1)
    with torch.no_grad():
        for p in agent.controller.parameters():
            p.zero_()  # every action scores 0: argmax plays action 0 (no-op) all bout
    assert scored[0] > 20 and agent.play(bouts=1)[0] <= 0  # the changed controller plays, not the file's
    with torch.no_grad():
        next(agent.memory.parameters()).view(-1)[0] = float("nan")
    with pytest.raises(ValueError, match=r"the memory's weights hold NaN or infinity \(lstm\.weight_ih_l0"):
        agent.play(bouts=1)


def test_a_failed_write_names_the_users_file_never_its_temporary_one(tmp_path, monkeypatch):
    from pathlib import Path

    from wmthesis.runs import write_json

    target = tmp_path / "summary.json"

    def refuse(self, *args, **kwargs):
        raise PermissionError(13, "Permission denied", str(self))

    monkeypatch.setattr(Path, "write_text", refuse)
    with pytest.raises(PermissionError) as caught:
        write_json(target, {"rows": []})
    assert caught.value.filename == str(target) and ".tmp" not in str(caught.value)
    assert not any(tmp_path.iterdir())  # nothing partial left


def test_solve_sokoban_checks_free_space_for_its_output_before_it_plays(tmp_path, monkeypatch, capsys):
    import shutil
    from collections import namedtuple

    import wmthesis.sokoban_search.evaluation as evaluation

    levels = tmp_path / "levels.txt"
    levels.write_text("#####\n#@$.#\n#####\n")
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda folder: usage(10**9, 10**9 - 10**5, 10**5))
    monkeypatch.setattr(evaluation, "solve_boards", lambda *a, **k: pytest.fail("played before the space was checked"))
    assert main(["solve-sokoban", str(levels), "--out", str(tmp_path / "out.json")]) != 0
    said = capsys.readouterr().err
    assert "out.json, the solutions of 1 level, needs about" in said and "MiB are free" in said
    assert not (tmp_path / "out.json").exists()
