"""Sokoban solved by search in a learned model: levels as text, the search, the model, the
experience file, resuming, saved solutions and bad input."""
import json
import re
import shutil
import zlib

import numpy as np
import pytest

from wmthesis.variants import Variant, Variants
import torch

from wmthesis.sokoban_search.config import SokobanSearchConfig
from wmthesis.config import for_profile
from wmthesis.envs.levels import LevelError, board_to_text, fit_board, parse_level, parse_levels, read_levels
from wmthesis.envs.sokoban import BOX, FLOOR, PLAYER, WALL, SokobanEnv, solve
from wmthesis.sokoban_search import accuracy, report
from wmthesis.sokoban_search.tables import target_rows
from wmthesis.sokoban_search.agent import SearchAgent, grid_env, grid_state, level_seeds, random_play
from wmthesis.sokoban_search.evaluation import check_solutions, solve_boards
from wmthesis.sokoban_search.experience import Experience
from wmthesis.sokoban_search.heuristic import turned
from wmthesis.sokoban_search.iteration import training_batches, fit_model, load_run, train_search_agent
from wmthesis.sokoban_search.model import SokobanModel
from wmthesis.sokoban_search.search import Simulator, best_first
from wmthesis.utils import half_precision
from wmthesis.runs import machine_name

# A Boxoban-style file: two levels after "; N" lines (level 0: generated, seed 1 of a 10x10 room
# with 2 boxes; level 1: a small classic-style level, rows indented with outside floor).
LEVELS = """; 0
##########
###      #
####  .$@#
##  . ####
##    ####
## $    ##
##     ###
##########
##########
##########

; 1
####
# .#
#  ###
#*@  #
#  $ #
#  ###
####
"""


# ---------------------------------------------------------------------------- levels as text

def test_a_level_in_text_reads_to_the_board_codes_and_back():
    board = parse_level("#####\n#@$.#\n#####")
    assert board.tolist() == [[0, 0, 0, 0, 0], [0, 5, 4, 2, 0], [0, 0, 0, 0, 0]]
    assert board_to_text(board) == "#####\n#@$.#\n#####"
    assert parse_level("#####\n#+*$#\n#   #\n#####")[1].tolist() == [0, 6, 3, 4, 0]  # + and * are targets


def test_a_boxoban_file_holds_several_levels_and_outside_floor_becomes_wall(tmp_path):
    path = tmp_path / "levels.txt"
    path.write_text(LEVELS)
    first, second = read_levels(path)
    assert first.shape == (10, 10) and int((first == BOX).sum()) == 2 and first[1, 3] == 1
    assert second.shape == (7, 6)
    assert second[6, 4] == 0 and second[0, 5] == 0  # rows shorter than the widest: padded with wall
    assert [b.shape for b in parse_levels(LEVELS.replace("; 1\n", "\n"))] == [(10, 10), (7, 6)]


@pytest.mark.parametrize("text, words", [
    ("#####\n#@$. \n#####", "enclosed"),
    ("#####\n#@$.@#\n######", "exactly one player"),
    ("#####\n#@$x#\n#####", "'x'"),
    ("#####\n#@ .#\n#####", "at least one box"),
    ("#####\n#@$ #\n#####", "exactly one target per box"),
    ("######\n#@$..#\n######", "exactly one target per box; found 1 boxes and 2 targets"),  # a spare target
])
def test_unplayable_levels_are_refused_naming_why(text, words, tmp_path):
    with pytest.raises(LevelError, match=words):
        parse_level(text, "my level")
    from wmthesis.envs.boxoban import load_levels

    levels = tmp_path / "mine.txt"  # in a file, after a good level: the file, the level's index and why
    levels.write_text(f"; 0\n#####\n#@$.#\n#####\n\n; 1\n{text}\n")
    with pytest.raises(LevelError, match=rf"^{re.escape(str(levels))}, level 1: .*{words}"):
        load_levels(levels)


def test_env_resets_to_a_text_level_padded_with_wall_to_its_room():
    env = SokobanEnv((10, 10), 4, observation="grid")
    env.reset(options={"board": "#####\n#@$.#\n#####"})
    assert env.board.shape == (10, 10) and env.board[1, 1] == PLAYER and (env.board[3:] == 0).all()
    _, reward, terminated, _, _ = env.step(3)  # push right: the box lands on the target
    assert terminated and reward == pytest.approx(10.9)
    with pytest.raises(LevelError, match="larger than the 7x7 room"):
        fit_board(np.zeros((8, 8), np.uint8), (7, 7))


# ---------------------------------------------------------------------------- search

def test_breadth_first_search_in_the_true_rules_finds_a_shortest_solution():
    first = parse_levels(LEVELS)[0]
    result = best_first(Simulator().expand, first[1:-1, 1:-1], budget=50_000)
    astar = solve(first)
    assert result.found and len(result.actions) <= len(astar)  # A* is optimal in pushes, not steps
    env = SokobanEnv((10, 10), 2, observation="grid")
    env.reset(options={"board": first})
    for action in result.actions:
        _, _, terminated, _, _ = env.step(action)
    assert terminated
    assert np.array_equal(result.states[0], first[1:-1, 1:-1]) and len(result.states) == len(result.actions) + 1


def test_a_heuristic_cuts_the_nodes_a_search_expands():
    level = parse_levels(LEVELS)[0][1:-1, 1:-1]
    blind = best_first(Simulator().expand, level, budget=50_000)

    def boxes_off_target(states):  # a test-only oracle: not something the agent is given
        return 3.0 * (states == BOX).reshape(len(states), -1).sum(1)

    guided = best_first(Simulator().expand, level, heuristic=boxes_off_target, budget=50_000)
    assert guided.found and guided.expanded < blind.expanded


def test_the_values_symmetries_are_the_squares_eight_and_keep_a_levels_shortest_solution():
    env = grid_env("sokoban-small")
    root = grid_state(env, env.reset(seed=3)[0])
    boards = [turned(torch.as_tensor(root)[None], k, m)[0].numpy() for k in range(4) for m in (False, True)]
    assert len({b.tobytes() for b in boards}) == 8 and np.array_equal(boards[0], root)
    assert np.array_equal(boards[2], np.rot90(root)) and np.array_equal(boards[3], np.rot90(root).T)
    shortest = {len(best_first(Simulator().expand, b, budget=50_000).actions) for b in boards}
    assert len(shortest) == 1  # so the steps to go, the value's label, holds for every symmetry


def test_the_policys_actions_turn_with_the_board_so_every_symmetry_keeps_a_solution():
    from wmthesis.envs.sokoban import apply_action
    from wmthesis.sokoban_search.policy import turned_actions

    env = grid_env("sokoban-small")
    env.reset(seed=5)
    board = env.board.copy()  # with its wall ring
    for k in range(4):
        for mirrored in (False, True):
            for action in range(8):
                after = board.copy()
                apply_action(after, action)
                view = turned(torch.as_tensor(board)[None], k, mirrored)[0].numpy().copy()
                moved = int(turned_actions(torch.tensor([action]), k, mirrored)[0])
                apply_action(view, moved)
                assert np.array_equal(view, turned(torch.as_tensor(after)[None], k, mirrored)[0].numpy())
                assert moved // 4 == action // 4  # a push stays a push, a move a move


def test_a_policy_prior_orders_the_expansions_along_the_solution_it_knows():
    level = parse_levels(LEVELS)[0][1:-1, 1:-1]
    blind = best_first(Simulator().expand, level, budget=50_000, batch=1)  # one node at a time: the order shows
    taken = dict(zip((s.tobytes() for s in blind.states[:-1]), blind.actions))

    def oracle(states):  # a test-only prior that knows one solution: not something the agent is given
        out = np.full((len(states), 8), np.log(1 / 8))
        for i, state in enumerate(states):
            if state.tobytes() in taken:
                out[i] = np.log(0.03 / 7)
                out[i, taken[state.tobytes()]] = np.log(0.97)
        return out

    guided = best_first(Simulator().expand, level, budget=50_000, batch=1, prior=oracle, prior_weight=1.0)
    assert guided.found and guided.actions == blind.actions and guided.expanded < blind.expanded / 10
    ignored = best_first(Simulator().expand, level, budget=50_000, batch=1, prior=oracle, prior_weight=0.0)
    assert ignored.expanded == blind.expanded


def test_a_policy_learns_the_actions_of_solutions_and_a_run_keeps_it(tmp_path):
    import dataclasses

    from wmthesis.sokoban_search.iteration import Run, fit_policy, save_run
    from wmthesis.sokoban_search.policy import Policy

    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small",), value_updates=600, batch_size=64)
    solver = SearchAgent(Simulator(), budget=5000)
    with Experience(tmp_path / "experience.h5") as experience:
        for seed in range(12):
            play = solver.play(grid_env("sokoban-small"), seed)
            assert play.solved
            experience.add("solutions", 1, states=play.transitions["states"], actions=play.transitions["actions"])
        torch.manual_seed(0)
        policy = Policy(7, 8, channels=32, blocks=2)
        accuracy = fit_policy(policy, experience, cfg, np.random.default_rng(0), progress=False)
    assert accuracy > 0.6  # chance is 1/8: it finds the player and the way its solutions go
    weighted = dataclasses.replace(cfg, prior_weight=1.0)
    model = SokobanModel(7, 8, np.array([-0.1, 0.9, 10.9], np.float32), channels=8, blocks=1)
    save_run(tmp_path, Run(model, None, [], 0, policy=policy), dataclasses.replace(weighted, value_channels=32, value_blocks=2))
    again = load_run(tmp_path)
    states = np.stack([grid_state(grid_env("sokoban-small"), grid_env("sokoban-small").reset(seed=s)[0]) for s in (20, 21)])
    assert np.array_equal(again.policy.log_probs(states), policy.log_probs(states))
    assert np.allclose(np.exp(policy.log_probs(states)).sum(1), 1.0, atol=1e-3)
    corridor = parse_level("#########\n#@ $  . #\n#########\n")[1:-1, 1:-1]  # any board size: 1x7 inside
    assert policy.log_probs(corridor[None]).shape == (1, 8)
    assert again.agent(weighted).prior is not None and again.agent(cfg).prior is None  # weight 0: no prior


def test_the_search_stops_at_its_budget_and_says_it_found_nothing():
    easy = parse_level("#######\n#@ $ .#\n#######\n")  # walk, then push right twice
    assert best_first(Simulator().expand, easy[1:-1, 1:-1], budget=50).found
    stuck = parse_level("#####\n#$  #\n#@ .#\n#####")  # the box sits in a corner
    result = best_first(Simulator().expand, stuck[1:-1, 1:-1], budget=30)
    assert not result.found and result.expanded <= 30 and result.info["exhausted"]


def test_backed_up_values_solve_bellmans_equation_over_the_search_graph():
    from wmthesis.sokoban_search.heuristic import backed_up
    from wmthesis.sokoban_search.search import GOAL, UNSEEN, SearchGraph

    # 0 -> 1, 2, 1 (two actions to one child count once); 1 -> the end, or back to 0;
    # 2 -> 3 (never expanded, estimated 5), 4 (never expanded, estimated 0: a floor of 1e-6),
    # and one action not looked at; 5 -> itself only: a region with no way out.
    graph = SearchGraph(states=np.zeros((6, 1, 1), np.uint8), expanded=np.array([0, 1, 2, 5]),
                        children=np.array([[1, 2, 1], [GOAL, 0, 0], [3, 4, UNSEEN], [5, 5, 5]]),
                        estimates=np.array([9, 9, 9, 5, 0, 9], np.float32))
    assert np.allclose(backed_up(graph, cap=50.0), [2, 1, 1, 50], atol=1e-5)
    graph.estimates[4] = 7.0
    assert np.allclose(backed_up(graph, cap=50.0), [2, 1, 6, 50])  # 2 goes through 3 now
    # the end found in mid-batch: node 3 was picked with 0..2 but none of its children looked at
    stopped = SearchGraph(graph.states, np.array([0, 1, 2, 3]),
                          np.array([[1, 2, 1], [GOAL, UNSEEN, UNSEEN], [3, 4, UNSEEN], [UNSEEN] * 3]),
                          np.array([9, 9, 9, 5, 7, 9], np.float32))
    assert np.allclose(backed_up(stopped, cap=50.0), [2, 1, 6, 5])  # 3 is its estimate, not a dead end


def test_a_breadth_first_graph_backs_up_the_shortest_solution_and_a_dead_level_to_the_cap():
    from wmthesis.sokoban_search.heuristic import backed_up

    level = parse_levels(LEVELS)[1]
    level = level[1:-1, 1:-1]
    far = lambda states: np.full(len(states), 1000.0)  # every unexpanded node far: only the ends count
    result = best_first(Simulator().expand, level, heuristic=far, budget=50_000, graph=True)
    graph = result.info["graph"]
    assert result.found and graph.expanded[0] == 0 and np.array_equal(graph.states[0], level)
    labels = backed_up(graph, cap=500.0)
    assert labels[0] == len(result.actions)  # breadth first: its plan is a shortest one
    on_plan = [next(i for i, s in enumerate(graph.states) if np.array_equal(s, state)) for state in result.states[:-1]]
    assert [labels[list(graph.expanded).index(i)] for i in on_plan] == list(range(len(result.actions), 0, -1))
    def boxes_off_target(states):  # a test-only oracle: not something the agent is given
        return 3.0 * (states == BOX).reshape(len(states), -1).sum(1)

    roomy = parse_levels(LEVELS)[0][1:-1, 1:-1]
    guided = best_first(Simulator().expand, roomy, heuristic=boxes_off_target, budget=50_000, batch=64, graph=True)
    g = guided.info["graph"]
    waiting = np.setdiff1d(np.arange(1, len(g.states)), g.expanded)  # some found in the last batch
    assert guided.found and len(waiting) and np.array_equal(g.estimates[waiting], boxes_off_target(g.states[waiting]))
    stuck = parse_level("#####\n#$  #\n#@ .#\n#####")[1:-1, 1:-1]  # the box in a corner: searched to the end
    dead = best_first(Simulator().expand, stuck, heuristic=far, budget=1000, graph=True)
    assert not dead.found and dead.info["exhausted"]
    assert np.all(backed_up(dead.info["graph"], cap=120.0) == 120.0)


def test_an_agent_keeping_backups_labels_what_its_searches_expanded_and_plays_as_before():
    stuck = parse_level("#####\n#$  #\n#@ .#\n#####")
    env = SokobanEnv((4, 5), 1, observation="grid")
    plain = SearchAgent(Simulator(), budget=1000).play(env, board=stuck)
    kept = SearchAgent(Simulator(), budget=1000, backups=4, cap=99.0).play(env, board=stuck)
    assert not kept.solved and kept.expanded == plain.expanded and len(plain.backed_up["labels"]) == 0
    assert kept.backed_up["states"].shape == (4, 2, 3) and np.all(kept.backed_up["labels"] == 99.0)
    first = parse_levels(LEVELS)[0]
    solver = SearchAgent(Simulator(), budget=50_000, backups=10_000)
    play = solver.play(SokobanEnv((10, 10), 2, observation="grid"), board=first)
    again = solver.play(SokobanEnv((10, 10), 2, observation="grid"), board=first)
    assert play.solved and play.actions == again.actions
    assert np.array_equal(play.backed_up["labels"], again.backed_up["labels"])  # the draw is seeded
    root = np.flatnonzero([np.array_equal(s, first[1:-1, 1:-1]) for s in play.backed_up["states"]])
    assert len(root) == 1 and play.backed_up["labels"][root[0]] <= len(play.actions)


def test_the_value_trains_on_the_last_rounds_backed_up_states_beside_the_solved_ones(tmp_path):
    from wmthesis.sokoban_search.iteration import training_batches, last_round, with_backed_up

    with Experience(tmp_path / "experience.h5") as experience:
        experience.add("backed_up", 1, states=np.zeros((3, 4, 4), np.uint8), labels=np.full(3, 1.0, np.float32))
        experience.add("backed_up", 2, states=np.ones((2, 4, 4), np.uint8), labels=np.full(2, 2.0, np.float32))
        experience.add("backed_up", 2, states=np.ones((2, 5, 5), np.uint8), labels=np.full(2, 3.0, np.float32))
        last = last_round(experience.arrays("backed_up"))
    assert sorted(last) == ["4x4", "5x5"] and np.all(last["4x4"]["to_go"] == 2.0)
    solved = {"4x4": {"states": np.full((6, 4, 4), 2, np.uint8), "to_go": np.full(6, 9.0, np.float32)},
              "3x3": {"states": np.full((6, 3, 3), 2, np.uint8), "to_go": np.full(6, 9.0, np.float32)}}
    rng = np.random.default_rng(0)
    batches = with_backed_up(training_batches(solved, 6, rng), last, 2, rng)
    for _ in range(20):
        batch = next(batches)
        if batch["states"].shape[1] == 4:  # 6 solved rows and 2 of the last round, of the same size
            assert batch["to_go"].tolist() == [9.0] * 6 + [2.0] * 2
        else:  # no backed-up board of this size: the solved rows alone
            assert batch["to_go"].tolist() == [9.0] * 6


# ---------------------------------------------------------------------------- the learned model

def test_the_model_expands_every_action_on_any_board_size():
    torch.manual_seed(0)
    model = SokobanModel(7, 8, [-0.1, 0.9], channels=8, blocks=1)
    for shape in ((5, 5), (8, 8), (3, 9)):
        nxt, rewards, dones, surprises = model.expand(np.zeros((2, *shape), np.uint8))
        assert nxt.shape == (2, 8, *shape) and rewards.shape == dones.shape == surprises.shape == (2, 8)
        assert set(np.unique(rewards)) <= {np.float32(-0.1), np.float32(0.9)}


def test_the_models_surprise_is_minus_the_log_probability_of_the_board_it_predicts():
    torch.manual_seed(0)
    model = SokobanModel(7, 8, [-0.1, 0.9], channels=8, blocks=1)
    states = np.random.default_rng(0).integers(7, size=(3, 4, 5)).astype(np.uint8)
    nxt, _, _, surprises = model.expand(states)
    with torch.no_grad(), half_precision(torch.device("cpu")):  # the precision expand runs in
        logits = model(torch.as_tensor(states))[0].float()  # (B, A, K, h, w)
    boards = torch.distributions.Categorical(logits=logits.permute(0, 1, 3, 4, 2))
    expected = -boards.log_prob(torch.as_tensor(nxt).long()).sum((2, 3))
    assert np.allclose(surprises, expected.numpy(), atol=1e-5) and (surprises > 0).all()


def test_a_prediction_whose_count_change_was_never_seen_is_blocked():
    rows = random_play("sokoban-small", 0, 30)
    model = SokobanModel(7, 8, [-0.1], channels=8, blocks=1)
    model.see_changes(rows["states"], rows["next_states"])
    larger = random_play("sokoban", 1, 10)  # count changes do not depend on the board's size
    assert set(map(tuple, model.count_changes(torch.as_tensor(larger["states"]),
                                              torch.as_tensor(larger["next_states"])).tolist())) \
        <= set(map(tuple, model.changes.tolist()))
    moved = int(np.flatnonzero((rows["states"] != rows["next_states"]).any((1, 2)))[0])
    state, real = rows["states"][moved], rows["next_states"][moved]
    vanished = np.where(state == PLAYER, FLOOR, state).astype(np.uint8)  # the player gone
    claims = np.stack([vanished, real] + [state] * 6)  # what the model is made to predict per action

    def forward(x):
        logits = 20.0 * torch.nn.functional.one_hot(torch.as_tensor(claims).long(), 7).permute(0, 3, 1, 2)
        return logits[None].float(), torch.zeros(1, 8, 1), torch.full((1, 8), 5.0)  # every action "ends"
    model.forward = forward
    children, _, dones, surprises = model.expand(state[None])
    assert np.array_equal(children[0, 0], state) and not dones[0, 0] and surprises[0, 0] == 0  # blocked
    assert np.array_equal(children[0, 1], real) and dones[0, 1]  # a change seen in real play stands


def test_an_end_predicted_on_a_board_never_seen_at_an_end_is_not_trusted():
    level = parse_level("#######\n#@ $ .#\n#######")
    plan = best_first(Simulator().expand, level[1:-1, 1:-1])
    states = _walk(level, plan.actions)
    model = SokobanModel(7, 8, [-0.1], channels=8, blocks=1)
    claims = np.stack([states[1], states[-1]] + [states[0]] * 6)  # a box still off its target; the end

    def forward(x):
        logits = 20.0 * torch.nn.functional.one_hot(torch.as_tensor(claims).long(), 7).permute(0, 3, 1, 2)
        return logits[None].float(), torch.zeros(1, 8, 1), torch.full((1, 8), 5.0)  # every action "ends"
    model.forward = forward
    assert model.expand(states[0][None])[2][0, :2].all()  # nothing seen yet: the head is trusted
    walled = np.full((6, 9), WALL, np.uint8)
    walled[1, 1:6] = states[-1][0]  # ends seen on boards with walls; the corridor shows none
    model.see_ends(walled[None])
    dones = model.expand(states[0][None])[2]
    assert not dones[0, 0] and dones[0, 1]  # a box off its target: never at an end


class _Liar:
    """The true rules, except that from ``state`` the action ``action`` is said to lead to
    ``claimed`` (with ``surprise``): a model's mistake that helps the search."""

    def __init__(self, state, action, claimed, surprise=0.0, done=False):
        self.key, self.action, self.claimed, self.surprise, self.done = state.tobytes(), action, claimed, surprise, done
        self.calls = 0

    def expand(self, states):
        children, rewards, dones, surprises = Simulator().expand(states)
        for i, state in enumerate(states):
            if state.tobytes() == self.key:
                children[i, self.action], dones[i, self.action] = self.claimed, self.done
                surprises[i, self.action] = self.surprise
        return children, rewards, dones, surprises


def _walk(board, actions):
    """The inner boards along ``actions`` under the true rules."""
    states = [board[1:-1, 1:-1]]
    for action in actions:
        states.append(Simulator().step(states[-1][None], np.array([action]))[0][0])
    return states


def test_doubt_keeps_the_search_off_a_transition_the_model_is_unsure_of():
    level = parse_level("########\n#@ $  .#\n########")  # push right three times
    truth = best_first(Simulator().expand, level[1:-1, 1:-1])
    states = _walk(level, truth.actions)
    liar = _Liar(states[0], 2, states[-2], surprise=3.0)  # "left" puts the box next to its target
    fooled = best_first(liar.expand, states[0], batch=1)  # one node at a time: the order is exact
    assert fooled.actions == [2, truth.actions[-1]]  # the shortcut through the mistake
    careful = best_first(liar.expand, states[0], batch=1, doubt=10.0)
    assert careful.actions == truth.actions


def test_the_agent_is_misled_by_a_models_mistake_once_not_at_every_search():
    level = parse_level("#######\n#@ $ .#\n#######")
    env = grid_env("sokoban-small")
    root = grid_state(env, env.reset(options={"board": level})[0])
    truth = best_first(Simulator().expand, root)
    liar = _Liar(root, 2, root.copy(), done=True)  # "left" is said to solve the level
    played = SearchAgent(liar, replans=1).play(env, board=level)
    assert played.solved and played.searches == 2 and played.actions == [2] + truth.actions


def test_a_search_that_spends_its_budget_starts_again_with_the_next_weight():
    level = parse_levels(LEVELS)[0]
    env = SokobanEnv((10, 10), 2, observation="grid")

    def noise(states):  # a misleading value: a fixed random number per board
        return np.array([zlib.crc32(s.tobytes()) % 1000 / 10.0 for s in states])

    breadth_first = best_first(Simulator().expand, level[1:-1, 1:-1], budget=2_000)
    assert breadth_first.found
    misled = SearchAgent(Simulator(), heuristic=noise, budget=2_000, weights=(1.0,)).play(env, board=level)
    assert not misled.solved and misled.expanded == 2_000
    again = SearchAgent(Simulator(), heuristic=noise, budget=2_000, weights=(1.0, 0.0)).play(env, board=level)
    assert again.solved and again.searches == 1 and again.expanded == 2_000 + breadth_first.expanded
    stuck = parse_level("#####\n#$  #\n#@ .#\n#####")  # every reachable board seen: no weight helps
    alone = best_first(Simulator().expand, stuck[1:-1, 1:-1], heuristic=noise, weight=1.0)
    assert SearchAgent(Simulator(), heuristic=noise, weights=(1.0, 0.0)).play(env, board=stuck).expanded == alone.expanded
    with pytest.raises(ValueError, match="weights"):
        SearchAgent(Simulator(), weights=())


def test_an_agent_asks_its_networks_about_a_state_once_per_level_and_plays_as_without_the_memo(monkeypatch):
    from wmthesis.sokoban_search import agent as agent_module

    level = parse_levels(LEVELS)[0]
    env = SokobanEnv((10, 10), 2, observation="grid")
    asked = {"model": [], "value": []}

    class Counted(Simulator):
        def expand(self, states):
            asked["model"].extend(s.tobytes() for s in states)
            return super().expand(states)

    def noise(states):  # a misleading value, so that the first search fails and the second goes over its states
        asked["value"].extend(s.tobytes() for s in states)
        return np.array([zlib.crc32(s.tobytes()) % 1000 / 10.0 for s in states])

    def play():
        return SearchAgent(Counted(), heuristic=noise, budget=2_000, weights=(1.0, 0.0)).play(env, board=level)

    memoised = play()
    assert memoised.solved and memoised.expanded > 2_000
    for name, states in asked.items():
        assert len(states) == len(set(states)), name  # no state asked twice
    model_calls = len(asked["model"])
    asked["model"].clear()

    class Forgetful(agent_module.Memo):  # the networks asked every time, as before the memo
        def expand(self, states):
            return self._expand(states)

    monkeypatch.setattr(agent_module, "Memo", Forgetful)
    plain = play()
    assert (plain.solved, plain.actions, plain.expanded) == (memoised.solved, memoised.actions, memoised.expanded)
    assert len(asked["model"]) == plain.expanded > model_calls  # the second search re-expanded states the first had


@pytest.mark.slow
def test_the_learned_model_becomes_exact_on_sokoban_small_in_a_short_run(tmp_path):
    cfg = SokobanSearchConfig(variants=("sokoban-small",), channels=32, batch_size=64, lr=3e-3)
    with Experience(tmp_path / "experience.h5") as experience:
        experience.add("transitions", 0, **random_play("sokoban-small", 0, 300))
        rewards = np.unique(experience.arrays("transitions")["5x5"]["rewards"])
        torch.manual_seed(0)
        model = SokobanModel(7, 8, rewards, cfg.channels, cfg.blocks)
        fit_model(model, experience, cfg, 1500, np.random.default_rng(0), progress=False)
    held_out = random_play("sokoban-small", 99, 30)
    measures = accuracy.one_step(model, held_out)
    assert measures["exact"] >= 0.98 > measures["exact_nothing_moves"]
    assert measures["player_vanished"] <= 0.005 and measures["reward_accuracy"] >= 0.98


def test_accuracy_of_the_true_rules_is_perfect_and_the_baseline_is_not():
    rows = random_play("sokoban-small", 3, 5)
    measures = accuracy.one_step(Simulator(), rows)
    assert measures["exact"] == 1.0 and measures["reward_accuracy"] == 1.0 and measures["end_accuracy"] == 1.0
    assert measures["exact_nothing_moves"] < 1.0
    states = np.concatenate([rows["states"][:120], rows["next_states"][119:120]])
    loop = accuracy.open_loop(Simulator(), [(states, rows["actions"][:120])], horizons=(10, 30))
    assert loop[10]["exact"] == 1.0 and loop[30]["exact"] == 1.0 and loop[30]["player_vanished"] == 0.0


# ---------------------------------------------------------------------------- the agent and its run

def test_the_agent_with_the_true_rules_solves_small_levels_and_its_solutions_replay():
    agent = SearchAgent(Simulator(), budget=5_000)
    env = grid_env("sokoban-small")
    seeds = level_seeds(0, 1000, 5)
    plays = [agent.play(env, s) for s in seeds]
    assert all(p.solved for p in plays)
    records = [p.record() for p in plays]
    assert check_solutions("sokoban-small", records) == [True] * 5
    records[0]["actions"] = records[0]["actions"][:-1]  # one step short
    assert check_solutions("sokoban-small", records[:1]) == [False]
    assert json.loads(json.dumps(records))[1]["seed"] == seeds[1]


def test_solve_boards_plays_levels_of_any_size_from_text():
    boards = parse_levels(LEVELS)
    results = solve_boards(SearchAgent(Simulator(), budget=20_000), boards, progress=False)
    assert [r["level"] for r in results] == [0, 1] and all(r["solved"] for r in results)
    assert results[1]["steps"] == len(results[1]["actions"]) > 0


def test_a_rounds_levels_played_in_parallel_parts_are_played_as_each_alone_in_seed_order():
    from wmthesis.sokoban_search.iteration import Run, play_in_parts

    run = Run(Simulator(), None, [], 0)  # breadth first in the true rules
    cfg = for_profile(SokobanSearchConfig, "smoke", budget=3000)
    seeds = level_seeds(0, 1, 11)  # more levels than parts, not a multiple of them
    plays = play_in_parts(run, cfg, "sokoban-small", seeds, progress=False)
    alone = SearchAgent(Simulator(), budget=3000, weights=cfg.weights, replans=cfg.replans)
    env = grid_env("sokoban-small")
    expected = [alone.play(env, s) for s in seeds]
    assert [p.seed for p in plays] == seeds
    assert [(p.solved, p.actions, p.expanded) for p in plays] == [(p.solved, p.actions, p.expanded) for p in expected]
    assert all(np.array_equal(p.transitions["states"], e.transitions["states"]) for p, e in zip(plays, expected))


def test_a_round_cut_off_in_its_play_replays_only_the_parts_it_had_not_finished(tmp_path, monkeypatch):
    import wmthesis.sokoban_search.iteration as iteration

    run = iteration.Run(Simulator(), None, [], 0)
    cfg = for_profile(SokobanSearchConfig, "smoke", budget=3000)
    seeds = level_seeds(0, 1, 11)
    played = []  # the first seed of each part played

    def serial(calls, progress, on_done, crash_after=None):
        for index, (fn, *args) in enumerate(calls):
            if index == crash_after:
                raise KeyboardInterrupt("the run was cut off")
            played.append(args[-1][0])
            on_done(index, fn(*args))

    monkeypatch.setattr(iteration, "parallel_calls", lambda c, p, d: serial(c, p, d, crash_after=3))
    with pytest.raises(KeyboardInterrupt):
        iteration.play_in_parts(run, cfg, "sokoban-small", seeds, False, tmp_path / "round-1")
    assert played == seeds[:3]
    monkeypatch.setattr(iteration, "parallel_calls", serial)
    resumed = iteration.play_in_parts(run, cfg, "sokoban-small", seeds, False, tmp_path / "round-1")
    assert played == seeds[:3] + seeds[3:iteration.ROUND_PARTS]  # only the five parts not kept
    whole = iteration.play_in_parts(run, cfg, "sokoban-small", seeds, False)
    assert [(p.seed, p.solved, p.actions) for p in resumed] == [(p.seed, p.solved, p.actions) for p in whole]
    played.clear()  # parts kept for other levels are not taken for these
    iteration.play_in_parts(run, cfg, "sokoban-small", level_seeds(0, 2, 11), False, tmp_path / "round-1")
    assert len(played) == iteration.ROUND_PARTS


def test_a_run_started_over_does_not_take_the_parts_an_earlier_run_left(tmp_path):
    import pickle

    import wmthesis.sokoban_search.iteration as iteration

    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small",))
    seeds = level_seeds(cfg.seed, 2, cfg.levels_per_round)  # round 1's levels
    (tmp_path / "round-1").mkdir()  # an earlier run's parts for the same levels, played by another model
    (tmp_path / "round-1" / "part-0.pkl").write_bytes(pickle.dumps({"seeds": seeds[0::iteration.ROUND_PARTS],
                                                                     "plays": ["not this run's play"]}))
    run = train_search_agent(tmp_path, cfg, progress=False)  # no state.pt: it starts over, parts and all
    assert run.history[1]["levels"] == cfg.levels_per_round and not (tmp_path / "round-1").exists()


def test_a_store_from_before_solutions_were_kept_reads_them_off_its_transitions(tmp_path):
    from wmthesis.sokoban_search.heuristic import steps_to_go

    solver, starved = SearchAgent(Simulator(), budget=5000), SearchAgent(Simulator(), budget=3, replans=0)
    env = grid_env("sokoban-small")
    plays = [(starved if seed % 3 == 0 else solver).play(env, seed) for seed in range(7)]
    assert 0 < sum(p.solved for p in plays) < 7
    with Experience(tmp_path / "now.h5") as now, Experience(tmp_path / "before.h5") as before:
        for store in (now, before):
            store.add("transitions", 0, **random_play("sokoban-small", 0, 2))
        for number, play in enumerate(plays, 1):  # as the rounds add them; only "now" keeps solutions
            for store in (now, before):
                store.add("transitions", number, **play.transitions)
                if play.solved:
                    states = play.transitions["states"]
                    store.add("to_go", number, states=states, labels=steps_to_go(states))
            if play.solved:
                now.add("solutions", number, states=play.transitions["states"], actions=play.transitions["actions"])
        kept, read = now.solutions(), before.solutions()
        assert before.count("solutions") == 0 and kept.keys() == read.keys()
        for key in kept:
            assert np.array_equal(kept[key]["states"], read[key]["states"])
            assert np.array_equal(kept[key]["actions"], read[key]["actions"])
        assert len(kept["5x5"]["actions"]) == sum(len(p.actions) for p in plays if p.solved)


def test_experience_drops_the_rounds_of_an_interrupted_round(tmp_path):
    rows = random_play("sokoban-small", 0, 2)
    with Experience(tmp_path / "e.h5") as experience:
        experience.add("transitions", 0, **rows)
        experience.add("transitions", 1, **rows)
        experience.add("to_go", 1, states=rows["states"][:3], labels=np.array([3, 2, 1], np.float32))
        assert experience.count() == 2 * len(rows["actions"]) and experience.count("to_go") == 3
        experience.drop_rounds(1)
        assert experience.count() == len(rows["actions"]) and experience.count("to_go") == 0
        kept = experience.arrays("transitions")["5x5"]
        assert np.array_equal(kept["states"], rows["states"]) and (kept["rounds"] == 0).all()


def test_a_run_resumes_to_the_same_result_and_refuses_another_config(tmp_path):
    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small",))
    first = train_search_agent(tmp_path / "a", cfg, progress=False)
    again = train_search_agent(tmp_path / "a", cfg, progress=False)  # nothing left to do
    assert again.history == first.history
    # Cut off after random play: the round runs again from the saved state to the same weights.
    straight = train_search_agent(tmp_path / "b", cfg, progress=False)
    import dataclasses
    partial = train_search_agent(tmp_path / "c", dataclasses.replace(cfg, rounds=0), progress=False)
    state = torch.load(tmp_path / "c" / "state.pt", weights_only=False)
    state["config"]["rounds"] = cfg.rounds
    torch.save(state, tmp_path / "c" / "state.pt")
    resumed = train_search_agent(tmp_path / "c", cfg, progress=False)
    assert partial.rounds_done == 0 and resumed.rounds_done == straight.rounds_done == 1
    for a, b in zip(resumed.model.state_dict().values(), straight.model.state_dict().values()):
        assert torch.equal(a, b)
    with pytest.raises(ValueError, match="another config"):
        train_search_agent(tmp_path / "a", dataclasses.replace(cfg, budget=7), progress=False)


def test_a_finished_runs_checkpoint_alone_serves_and_an_unfinished_ones_is_refused(tmp_path):
    """As the committed agents are kept: state.pt without experience.h5."""
    import dataclasses

    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small",))
    finished = train_search_agent(tmp_path / "run", cfg, progress=False)
    (tmp_path / "alone").mkdir()
    shutil.copy(tmp_path / "run" / "state.pt", tmp_path / "alone" / "state.pt")
    again = train_search_agent(tmp_path / "alone", cfg, progress=False)  # nothing to train
    assert again.history == finished.history
    for a, b in zip(again.model.state_dict().values(), finished.model.state_dict().values()):
        assert torch.equal(a, b)
    more = dataclasses.replace(cfg, rounds=2)  # the same checkpoint, one round short of this config
    state = torch.load(tmp_path / "alone" / "state.pt", weights_only=False)
    state["config"]["rounds"] = 2
    torch.save(state, tmp_path / "alone" / "state.pt")
    (tmp_path / "alone" / "experience.h5").unlink()
    with pytest.raises(ValueError, match="after round 1 of 2.*cannot resume without it"):
        train_search_agent(tmp_path / "alone", more, progress=False)


def test_a_run_saved_before_backed_up_values_reads_as_one_without_them(tmp_path):
    import dataclasses

    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small",), backups=0)
    assert for_profile(SokobanSearchConfig, "smoke").backups > 0  # the default keeps them now
    train_search_agent(tmp_path, cfg, progress=False)
    saved = torch.load(tmp_path / "state.pt", weights_only=False)
    for name in ("backups", "backup_cap", "backup_fraction"):  # as a run saved before they existed
        del saved["config"][name]
    torch.save(saved, tmp_path / "state.pt")
    assert load_run(tmp_path, cfg).rounds_done == 1
    with pytest.raises(ValueError, match="'backups': \\(0, 200\\)"):
        load_run(tmp_path, dataclasses.replace(cfg, backups=200))


def test_a_corrupt_checkpoint_is_named_and_left_alone(tmp_path):
    (tmp_path / "state.pt").write_bytes(b"not a checkpoint")
    with pytest.raises(ValueError, match="delete it to start over"):
        load_run(tmp_path)
    assert (tmp_path / "state.pt").read_bytes() == b"not a checkpoint"


def test_an_unknown_variant_fails_with_the_valid_ones():
    with pytest.raises((ValueError, KeyError), match="sokoban-small"):
        grid_env("sokoban-huge")


def test_a_curriculum_trains_on_boxoban_train_levels_and_never_on_the_valid_files(tmp_path):
    from wmthesis.envs.boxoban import boxoban_levels

    train = {b.tobytes() for b in boxoban_levels("boxoban-medium-train:000")}
    for seed in level_seeds(0, 2, 3):  # a round's levels: each one of the file's boards, drawn by the seed
        env = grid_env("boxoban-medium-train:000")
        env.reset(seed=seed)
        assert env.board.tobytes() in train
    for name in ("boxoban-unfiltered-valid", "boxoban-medium-valid:000"):
        with pytest.raises(ValueError, match="only Boxoban's train files"):
            train_search_agent(tmp_path, for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small", name)))
    with pytest.raises(ValueError, match="kept for an external check"):
        grid_env("boxoban-hard")
    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("boxoban-unfiltered-train:001",), random_levels=3)
    run = train_search_agent(tmp_path / "run", cfg, progress=False)
    assert [h["variant"] for h in run.history] == ["random play", "boxoban-unfiltered-train:001"]
    assert run.history[1]["levels"] == cfg.levels_per_round
    assert all(h["wall_seconds"] > 0 for h in run.history)  # each stage timed, random play and the round
    from wmthesis.experiments.sokoban_search import training_seconds
    assert training_seconds(run.history) == sum(h["wall_seconds"] for h in run.history)
    assert training_seconds([{"round": 0}, *run.history[1:]]) is None  # a stage saved before stages were timed


def test_the_rounds_search_with_their_own_budget_and_the_evaluation_with_its_own(tmp_path, monkeypatch):
    import wmthesis.sokoban_search.iteration as iteration

    budgets = []
    real = iteration.play_in_parts
    monkeypatch.setattr(iteration, "play_in_parts", lambda run, cfg, *a: budgets.append(cfg.budget) or real(run, cfg, *a))
    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small",), budget=50, round_budget=150)
    run = train_search_agent(tmp_path, cfg, progress=False)
    assert budgets == [150] and run.agent(cfg).budget == 50  # the round's levels with 150, the evaluation 50


def test_a_lever_is_measured_on_the_validation_files_only_and_tabled(tmp_path, monkeypatch):
    from wmthesis.envs.boxoban import BOXOBAN_SPLITS
    from wmthesis.experiments.sokoban_search import validate
    from wmthesis.sokoban_search.tables import lever_rows

    with pytest.raises(ValueError, match="valid: baseline, no-backups, generated"):
        validate("bigger-brain", "smoke")
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    result = validate("strong-expert", "smoke", seed=1, levels=3, progress=False)
    assert result["changes"] == {"round_budget": 60_000}
    for kind, row in result["rows"].items():
        assert row["levels"] == 3 and row["source"].startswith(BOXOBAN_SPLITS["validation"][kind])
        assert row["source"].startswith(("boxoban-unfiltered-valid:000-001", "boxoban-medium-valid:000-001"))
    (row,) = lever_rows("smoke", seed=1)
    assert row[:2] == ["strong-expert", "round_budget=60000"] and row[4] == 3
    assert row[2] == f"{100 * result['rows']['unfiltered']['solve_rate']:.1f}"


def test_validation_and_report_figures_over_seeds_give_each_seed_then_the_mean_std_and_t_interval(tmp_path, monkeypatch):
    import dataclasses

    from wmthesis.sokoban_search.report import search_record
    from wmthesis.sokoban_search.tables import lever_seed_rows, report_seed_rows
    from wmthesis.sokoban_search.iteration import evaluation_search

    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    search = search_record(evaluation_search(for_profile(SokobanSearchConfig, "quick", inputs="pixels")))  # quick's today
    for seed, (unfiltered, medium) in {2: (0.98, 0.90), 0: (1.0, 0.94), 1: (0.99, 0.80)}.items():
        folder = tmp_path / "results" / "sokoban-search" / f"quick-seed{seed}"
        folder.mkdir(parents=True)
        rows = {k: {"solve_rate": rate, "levels": 100, "nodes_per_level": 1000.0 * (seed + 1),
                    "seconds_per_level": seconds}
                for k, rate, seconds in (("unfiltered", unfiltered, 1.0), ("medium", medium, 4.0))}
        (folder / "validation-baseline.json").write_text(json.dumps(
            {"lever": "baseline", "seed": seed, "rows": rows, "env_steps": 420_000}))
        if seed < 2:  # the closing figures of two seeds
            (folder / "boxoban-report-1000.json").write_text(json.dumps(
                {"levels": 1000, "seed": seed, "rows": rows, "env_steps": 420_000, "search": search}))
        else:  # and one searched with another budget, which is not today's agent
            other = search_record(dataclasses.replace(for_profile(SokobanSearchConfig, "quick"), budget=1))
            (folder / "boxoban-report-1000.json").write_text(json.dumps(
                {"levels": 1000, "seed": seed, "rows": rows, "env_steps": 420_000, "search": other}))
    (tmp_path / "results" / "sokoban-search" / "smoke-seed0").mkdir()  # another profile: not read
    rows = lever_seed_rows("baseline", "quick")
    assert [r[0] for r in rows[:3]] == [0, 1, 2] and rows[1][1:6] == ["99.0", "80.0", 100, "2,000", "2.50"]
    # medium 94, 80, 90: mean 88.0, sample std sqrt(((6)^2 + (8)^2 + (2)^2) / 2) = sqrt(52) = 7.2; the
    # interval's half width t(0.975, 2) std / sqrt(3) = 4.303 * 7.211 / 1.732 = 17.9, clipped at 100%
    assert rows[3] == ["mean ± std [95% CI], 3 seeds", "99.0 ± 1.0 [96.5, 100.0]", "88.0 ± 7.2 [70.1, 100.0]",
                       "", "", "", ""]
    assert lever_seed_rows("generated", "quick") == []
    # unfiltered 100 and 99, medium 94 and 80: half widths t(0.975, 1) std / sqrt(2) = 12.706 * 0.707 / 1.414
    # and 12.706 * 9.899 / 1.414
    report = report_seed_rows(1000, "quick")
    assert [r[0] for r in report[:2]] == [0, 1]
    assert report[2][:3] == ["mean ± std [95% CI], 2 seeds", "99.5 ± 0.7 [93.1, 100.0]", "87.0 ± 9.9 [0.0, 100.0]"]  # clipped to 0-100%
    assert report_seed_rows(500, "quick") == []
    assert [r[0] for r in report_seed_rows(1000, "quick") if isinstance(r[0], int)] == [0, 1]  # not seed 2's budget


def test_the_closing_evaluation_plays_more_report_levels_and_only_those_a_smaller_one_did_not(tmp_path, monkeypatch):
    import importlib
    import os

    experiment = importlib.import_module("wmthesis.experiments.sokoban_search")  # the module, not its function
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    monkeypatch.setattr(os, "cpu_count", lambda: 1)  # the parts in this process, so that the spy sees them
    played, real = [], report.solve_boards
    monkeypatch.setattr(report, "solve_boards", lambda agent, boards, **kw: played.append(kw["levels"]) or real(agent, boards, **kw))
    first = experiment.evaluate_report("smoke", seed=3, levels=2, progress=False)  # trains the pixel agent first
    assert played == [[0], [1]] * 2  # unfiltered, then medium: each kind's two parts
    cfg = for_profile(SokobanSearchConfig, "smoke", seed=3, inputs="pixels")
    assert first["env_steps"] == sum(h["env_steps"] for h in load_run(experiment.work_folder("smoke", 3) / "pixels", cfg).history) > 0
    assert not (experiment.work_folder("smoke", 3) / "grid").exists()  # the pixel run alone
    played.clear()
    more = experiment.evaluate_report("smoke", seed=3, levels=5, progress=False)
    assert played == [[2, 4], [3]] * 2  # the first two levels of each kind come from the smaller evaluation
    for kind, row in more["rows"].items():
        assert row["levels"] == 5 and row["source"].startswith(experiment.BOXOBAN_SPLITS["report"][kind])
        assert set(first["rows"][kind]["failed_levels"]) <= set(row["failed_levels"]) | {0, 1}
        assert row["replayed"] == row["solved"]
    saved = json.loads((tmp_path / "results" / "sokoban-search" / "smoke-seed3" / "boxoban-report-5.json").read_text())
    assert saved["rows"]["medium"]["levels"] == 5 and saved["levels"] == 5 and saved["search"]["budget"] == cfg.budget
    history = load_run(experiment.work_folder("smoke", 3) / "pixels", cfg).history
    assert saved["training_wall_seconds"] > 0
    assert saved["training_wall_seconds"] == pytest.approx(sum(h["wall_seconds"] for h in history), abs=0.1)
    assert saved["machine"] == machine_name()  # this machine, as every metrics.json names it
    # twice the budget at evaluation: a play that stayed under the old budget is the same, any other is played again
    work = experiment.work_folder("smoke", 3)
    for count, part in ((2, 0), (2, 1), (5, 0), (5, 1)):
        path = work / f"eval-boxoban-pixels-unfiltered-{count}-{part}.json"
        kept = json.loads(path.read_text())
        for play in kept["plays"]:
            play.update(expanded=cfg.budget - 1, kept=True) if play["level"] == 2 else play.update(expanded=cfg.budget)
        path.write_text(json.dumps(kept))
    medium = [[p["level"] for p in json.loads((work / f"eval-boxoban-pixels-medium-5-{part}.json").read_text())["plays"]
               if p["expanded"] >= cfg.budget] for part in range(2)]  # as they were played
    monkeypatch.setattr(experiment, "for_profile", lambda cls, profile, **kw: for_profile(cls, profile, eval_budget=2 * cfg.budget, **kw))
    played.clear()
    bigger = experiment.evaluate_report("smoke", seed=3, levels=5, progress=False)
    assert played == [[0, 4], [1, 3], *medium]  # unfiltered: all but level 2
    assert bigger["search"]["budget"] == 2 * cfg.budget
    again = json.loads((work / "eval-boxoban-pixels-unfiltered-5-0.json").read_text())
    assert [p.get("kept", False) for p in again["plays"]] == [False, True, False] and again["search"]["budget"] == 2 * cfg.budget


def test_the_evaluations_time_is_the_first_complete_one_of_its_search_and_unknown_after_another_search():
    from wmthesis.experiments.sokoban_search import evaluation_seconds

    search, other = {"budget": 40_000}, {"budget": 20_000}
    assert evaluation_seconds(None, search, 12.0) == 12.0  # the first: timed now
    assert evaluation_seconds({"search": search, "evaluation_wall_seconds": 900.0}, search, 12.0) == 900.0
    assert evaluation_seconds({"search": other, "evaluation_wall_seconds": 900.0}, search, 12.0) is None
    assert evaluation_seconds({"evaluation_wall_seconds": 900.0}, search, 12.0) is None  # written before records


def test_an_evaluation_saved_by_another_search_is_computed_again_and_one_by_the_same_is_kept(tmp_path):
    import importlib

    experiment = importlib.import_module("wmthesis.experiments.sokoban_search")
    path = tmp_path / "eval.json"
    path.write_text(json.dumps({"plays": [{"level": 0}], "search": {"budget": 1}}))
    fresh = '{"plays": [], "search": {"budget": 2}}'
    experiment.run_jobs({"same": (path, (json.loads, fresh), {"budget": 1})}, progress=False)
    assert json.loads(path.read_text())["plays"] == [{"level": 0}]  # the same search: kept
    experiment.run_jobs({"other": (path, (json.loads, fresh), {"budget": 2})}, progress=False)
    assert json.loads(path.read_text()) == json.loads(fresh)  # another: computed again
    path.write_text(json.dumps({"plays": [{"level": 0}]}))  # a file that records no search serves no search
    experiment.run_jobs({"other": (path, (json.loads, fresh), {"budget": 2})}, progress=False)
    assert json.loads(path.read_text()) == json.loads(fresh)


def test_a_search_only_lever_searches_the_baselines_run_without_training_another(tmp_path, monkeypatch):
    import dataclasses
    import importlib

    experiment = importlib.import_module("wmthesis.experiments.sokoban_search")  # the module, not its function
    monkeypatch.setenv("WMTHESIS_DATA", str(tmp_path))
    one_node = Variant("one-node", "one node a search", dict(budget=1))  # no search can solve in one node
    monkeypatch.setattr(experiment, "LEVERS", Variants("sokoban-search", *experiment.LEVERS.values(), one_node))
    baseline = experiment.validate("baseline", "smoke", seed=2, levels=2, progress=False)
    pixels = experiment.work_folder("smoke", 2) / "pixels"
    trained = (pixels / "state.pt").stat().st_mtime_ns
    searched = []
    real = experiment.run_jobs
    monkeypatch.setattr(experiment, "run_jobs", lambda jobs, progress: searched.extend(jobs.values()) or real(jobs, progress))
    starved = experiment.validate("one-node", "smoke", seed=2, levels=2, progress=False)
    # every job loads the baseline's run as it was trained, and searches with one node
    cfg = experiment.for_profile(experiment.SokobanSearchConfig, "smoke", seed=2, inputs="pixels")
    assert len(searched) == 4 and all(args[2] == cfg and args[7] == dataclasses.replace(cfg, budget=1)
                                      and search["budget"] == 1 for _, args, search in searched)
    assert (pixels / "state.pt").stat().st_mtime_ns == trained  # nothing trained again
    assert not (experiment.work_folder("smoke", 2) / "lever-one-node").exists()
    assert sorted(p.name for p in pixels.glob("validation-one-node-*.json")) == [
        f"validation-one-node-{kind}-2-{part}.json" for kind in ("medium", "unfiltered") for part in range(2)]
    for row in starved["rows"].values():  # one node a search, each weight, each replan
        assert row["solve_rate"] == 0 and row["nodes_per_level"] <= len(cfg.weights) * (1 + cfg.replans)
    assert starved["env_steps"] == baseline["env_steps"] and starved["changes"] == {"budget": 1}
    # a policy prior fitted once on the baseline's own solutions, searched with, nothing else trained
    with pytest.raises(ValueError, match="solved no level"):  # the smoke run solves none
        experiment.validate("prior-afterwards", "smoke", seed=2, levels=2, progress=False)
    run = experiment.load_run(pixels, cfg)
    solver = SearchAgent(Simulator(), budget=5000)
    with Experience(pixels / "experience.h5") as experience:  # as if it had solved these
        for seed in range(6):
            play = solver.play(grid_env("sokoban-small"), seed)
            experience.add("solutions", 1, states=run.inputs.from_grid(play.transitions["states"]),
                           actions=play.transitions["actions"])
    experiment.validate("prior-afterwards", "smoke", seed=2, levels=2, progress=False)
    assert (pixels / "state.pt").stat().st_mtime_ns == trained
    assert len(searched) == 8 and all(args[7] == dataclasses.replace(cfg, prior_weight=1.0) for _, args, _ in searched[4:])
    run = experiment.load_run(pixels, cfg)
    fitted = (pixels / "policy-afterwards.pt").stat().st_mtime_ns
    policy = experiment.policy_afterwards(pixels, run, cfg)
    assert (pixels / "policy-afterwards.pt").stat().st_mtime_ns == fitted  # read back, not fitted again
    again = tmp_path / "again"  # the same run fitted again, whatever the process's random state: the same policy
    again.mkdir()
    for name in ("state.pt", "experience.h5"):
        shutil.copyfile(pixels / name, again / name)
    torch.manual_seed(123)
    refitted = experiment.policy_afterwards(again, run, cfg)
    assert all(torch.equal(a, b) for a, b in zip(policy.state_dict().values(), refitted.state_dict().values()))
    assert not list(pixels.glob("*.partial.json"))  # each part's levels, saved one by one, now in its file
    # a part cut off after its first level plays only the others
    record = report.search_record(cfg)
    partial = tmp_path / "cut.partial.json"
    partial.write_text(json.dumps({"plays": [{"level": 0, "solved": True, "expanded": -1}], "search": record}))
    source = experiment.BOXOBAN_SPLITS["validation"]["unfiltered"]
    plays = report.evaluate_boxoban(pixels, cfg, source, 4, 0, False, None, partial)["plays"]
    assert [p["level"] for p in plays] == [0, 2] and plays[0]["expanded"] == -1 and plays[1]["expanded"] >= 0
    assert [p["level"] for p in json.loads(partial.read_text())["plays"]] == [0, 2]
    # a part saved by another search is played again: with the evaluation's budget of one node, nothing is solved
    bigger = dataclasses.replace(cfg, eval_budget=1)
    assert experiment.load_run(pixels, bigger) is not None  # the evaluation's fields do not tell trained runs apart
    partial.write_text(json.dumps({"plays": [{"level": 0, "solved": True, "expanded": cfg.budget}], "search": record}))
    again = report.evaluate_boxoban(pixels, bigger, source, 4, 0, False, None, partial)
    assert again["search"]["budget"] == 1 and not any(p["solved"] for p in again["plays"])
    assert all(p["expanded"] <= len(cfg.weights) * (1 + cfg.replans) for p in again["plays"])
    # so does a job on our generator's levels, and a level played again is played the same
    cut = tmp_path / "cut-generated.partial.json"
    cut.write_text(json.dumps({"plays": [{"seed": 5, "solved": True, "expanded": -1}], "search": record}))
    plays = report.evaluate_levels(pixels, cfg, "sokoban-small", [5, 6, 7], False, cut)["plays"]
    assert [p["seed"] for p in plays] == [5, 6, 7] and plays[0]["expanded"] == -1 and plays[1]["expanded"] >= 0
    assert [p["seed"] for p in json.loads(cut.read_text())["plays"]] == [5, 6, 7]
    timeless = lambda plays: [{k: v for k, v in p.items() if k != "seconds"} for p in plays]  # noqa: E731
    assert timeless(report.evaluate_levels(pixels, cfg, "sokoban-small", [7, 6], False)["plays"]) == timeless(plays[:0:-1])
    assert run.agent(dataclasses.replace(cfg, prior_weight=1.0)).prior is None  # the run itself has none...
    run.policy = policy
    assert run.agent(dataclasses.replace(cfg, prior_weight=1.0)).prior is not None  # ...the fitted one is used


# ---------------------------------------------------------------------------- pixels

def test_cell_codes_learned_from_pixels_stand_for_one_cell_type_each_and_decode_exactly():
    from wmthesis.sokoban_search.cells import GRID, PixelInputs, code_table, crop_ring, fit_coder, render_cells

    states = random_play("sokoban", 0, 30)["states"]
    coder = fit_coder(render_cells(states[::5]), tile_size=8, n_codes=8)
    unseen = random_play("sokoban-small", 5, 10)["states"]
    codes = coder.encode(render_cells(unseen))
    table = code_table(codes, unseen)
    assert np.array_equal(table[codes], unseen)  # every cell's code names its true type
    assert len(set(table[np.unique(codes)])) == len(np.unique(codes))  # no two codes for one type
    assert np.array_equal(coder.decode(codes), render_cells(unseen))
    env = SokobanEnv((10, 10), 4, observation="rgb", tile_size=8)
    observation, _ = env.reset(seed=4)
    inputs = PixelInputs(coder)
    assert np.array_equal(crop_ring(observation, 8), render_cells(env.board[None, 1:-1, 1:-1])[0])
    assert np.array_equal(inputs.observe(env, observation), inputs.from_grid(env.board[None, 1:-1, 1:-1])[0])
    import wmthesis.sokoban_search.cells as cells
    whole = inputs.from_grid(unseen)
    with pytest.MonkeyPatch.context() as patch:  # coded a few boards at a time: the same codes, in order
        patch.setattr(cells, "FRAMES_AT_ONCE", 7)
        assert np.array_equal(inputs.from_grid(unseen), whole) and len(whole) > 7
        assert inputs.from_grid(unseen[:0]).shape == (0, *unseen.shape[1:])
    # The true rules over these codes (the reference row with the pixel agent's own value): the same
    # transitions as over the cell types, coded.
    actions = np.arange(len(unseen)) % 8
    types, coded = Simulator().step(unseen, actions), Simulator(inputs.type_codes()).step(whole, actions)
    assert (types[0] != unseen).any() and (types[1] != types[1][0]).any()  # boards move, rewards differ
    assert np.array_equal(coded[0], inputs.from_grid(types[0]))
    assert np.array_equal(coded[1], types[1]) and np.array_equal(coded[2], types[2])
    assert np.array_equal(GRID.type_codes(), np.arange(7))
    with pytest.raises(ValueError, match="share a code"):
        Simulator(np.array([0, 1, 2, 3, 4, 5, 5]))


def test_a_pixel_run_plays_from_frames_and_saves_its_codes(tmp_path):
    import dataclasses

    cfg = for_profile(SokobanSearchConfig, "smoke", variants=("sokoban-small",), inputs="pixels")
    run = train_search_agent(tmp_path, cfg, progress=False)
    assert run.inputs.name == "pixels" and run.model.n_codes == cfg.codes
    loaded = load_run(tmp_path, cfg)
    assert np.array_equal(loaded.inputs.coder.codebook, run.inputs.coder.codebook)
    env = run.agent(cfg).env("sokoban-small")
    assert env.observation == "rgb"
    with pytest.raises(ValueError, match="inputs"):
        train_search_agent(tmp_path / "x", dataclasses.replace(cfg, inputs="voxels"), progress=False)


def test_frames_that_are_not_whole_tiles_of_the_coder_are_refused_naming_both_sizes():
    from wmthesis.sokoban_search.cells import CellCoder

    coder = CellCoder(np.zeros((8, 8 * 8 * 3), np.float32), tile_size=8)
    assert coder.encode(np.zeros((1, 40, 40, 3), np.uint8)).shape == (1, 5, 5)  # any board size of whole tiles
    with pytest.raises(ValueError, match="frames of 36x40 pixels are not whole tiles of 8x8"):
        coder.encode(np.zeros((1, 36, 40, 3), np.uint8))


def test_the_target_table_says_by_how_much_a_target_is_missed():
    loop = {"exact": 0.9372, "sequences": 239, "player_vanished": 0.0}
    measures = {"one_step": {"exact": 1.0, "transitions": 6000, "player_vanished": 0.0}, "open_loop": {"30": loop}}
    metrics = {"tables": {"sokoban": {"agent, learned model (pixels)": {"solve_rate": 0.88}}},
               "env_steps": {"pixels": 263_231}, "accuracy": {"sokoban": {"pixels": measures}},
               "first_run_wall_seconds": 4_600}
    verdicts = {row[0]: row[2] for row in target_rows(metrics)}
    assert verdicts["sokoban from pixels: at least 90% solved"] == "missed by 2.0%"
    assert verdicts["sokoban from pixels, model exact open loop +30: at least 95.0%"] == "missed by 1.28%"
    assert verdicts["sokoban from pixels, model exact one step: at least 99.5%"] == "met"
    assert verdicts["sokoban from pixels: no player vanishes"] == "met"
    assert verdicts["pixels: fewer than 1,000,000 environment steps"] == "met"
    assert verdicts["the whole experiment within 75 minutes (first run)"] == "missed by 1.7 min"
    # A run trained elsewhere (validate sokoban-search): its stages' own wall times and the evaluation's.
    timed = {**metrics, "training_wall_seconds": 2_400.0, "evaluation_wall_seconds": 600.0}
    assert {row[0]: row[2] for row in target_rows(timed)}[
        "the whole experiment within 75 minutes (training's stages + evaluation)"] == "met"
    measures["open_loop"] = {30: {"sequences": 0}}  # no plan 30 steps long (a smoke run)
    verdicts = {row[0]: row[2] for row in target_rows(metrics)}
    assert verdicts["sokoban from pixels, model exact open loop +30: at least 95.0%"] == "not measured"


def test_the_boxoban_target_table_says_by_how_much_each_of_issue_30s_targets_is_missed():
    from wmthesis.sokoban_search.tables import boxoban_target_rows

    agent = "agent, learned model (pixels)"
    tables = {"unfiltered": {agent: {"levels": 500, "solve_rate": 0.986, "seconds_per_level": 1.5}},
              "medium": {agent: {"levels": 500, "solve_rate": 0.87, "seconds_per_level": 6.9}}}
    metrics = {"boxoban": {"tables": tables}, "env_steps": {"pixels": 398_657},
               "training_wall_seconds": 2_818.0, "evaluation_wall_seconds": 1_800.0}
    verdicts = {row[0]: (row[1], row[2]) for row in boxoban_target_rows(metrics)}
    assert verdicts["Boxoban unfiltered from pixels: at least 99% (this seed, 500 report levels)"] == ("98.6%", "missed by 0.4%")
    assert verdicts["Boxoban medium from pixels: at least 85% (this seed, 500 report levels)"] == ("87.0%", "met")
    assert verdicts["seconds a level on one core, both kinds: at most 5"] == ("4.20 s", "met")  # (1.5 + 6.9) / 2
    assert verdicts["fewer than 1,000,000 environment steps"] == ("398,657", "met")
    assert verdicts["a quick seed trained here within 75 minutes (training's stages + evaluation)"] == ("77.0 min",
                                                                                                "missed by 2.0 min")
    untimed = {k: v for k, v in metrics.items() if k != "training_wall_seconds"}  # trained before stages were timed
    assert len(boxoban_target_rows(untimed)) == len(verdicts) - 1


def test_the_tables_give_the_thesis_a_figure_only_on_the_levels_it_played():
    """The thesis played a generator's 10x10 levels (5.1.2), never our 7x7 ones nor Boxoban: its row
    says so there, also for a run written when every table gave it 0."""
    from wmthesis.sokoban_search.evaluation import NOT_PLAYED, thesis_row
    from wmthesis.sokoban_search.figures import results_table
    from wmthesis.sokoban_search.tables import boxoban_rows

    assert thesis_row("sokoban") == {"solve_rate": 0.0}
    assert thesis_row("sokoban-small")["solve_rate"] is None and thesis_row("medium")["note"] == NOT_PLAYED
    agent = "agent, learned model (pixels)"
    rows = {"thesis": {"solve_rate": 0.0}, agent: {"solve_rate": 0.5, "solved": 1, "levels": 2}}  # as runs wrote them
    lines = {line.split(" | ")[0]: line for line in results_table(rows, "sokoban-small").splitlines()}
    assert lines["| thesis"].startswith(f"| thesis | {NOT_PLAYED} |") and lines[f"| {agent}"].startswith(f"| {agent} | 0.5 | 1 | 2 |")
    assert "| thesis | 0 |" in results_table(rows, "sokoban") and "| thesis | 0 |" in results_table(rows)
    metrics = {"boxoban": {"tables": {kind: rows for kind in ("unfiltered", "medium")}}, "env_steps": {"pixels": 10}}
    table = {row[0]: row for row in boxoban_rows(metrics)}
    assert table["thesis"][1:3] == [NOT_PLAYED, NOT_PLAYED] and table[agent][1:3] == ["50.0", "50.0"]


def test_a_batch_draws_its_special_fractions_among_the_rows_they_mark():
    rows = np.arange(1000)
    groups = {"5x5": {"states": np.zeros((1000, 5, 5), np.uint8), "rewards": (rows % 100 == 0).astype(np.float32),
                      "rounds": (rows >= 900).astype(np.int64), "index": rows}}
    special = [(0.25, lambda g: g["rewards"] > 0), (0.5, lambda g: g["rounds"] > 0)]
    batch = next(training_batches(groups, 64, np.random.default_rng(0), special))
    index = batch["index"].numpy()
    assert (index[:16] % 100 == 0).all() and (index[16:48] >= 900).all()
    uniform = next(training_batches(groups, 64, np.random.default_rng(0)))["index"].numpy()
    assert (uniform >= 900).mean() < 0.3  # without them, about a tenth
    with pytest.raises(ValueError, match="more than 1"):
        next(training_batches(groups, 64, np.random.default_rng(0), [(0.6, special[0][1]), (0.6, special[1][1])]))
