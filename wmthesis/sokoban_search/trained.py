"""A trained Sokoban search agent as :func:`wmthesis.load` gives it (beyond the thesis, its chapter
1's aim): the learned model over discrete cells, the learned value, and the best-first search
that plans in them, on the 10x10 levels of four boxes it was scored on.

    agent = wmthesis.load("sokoban-search")
    record = agent.solve('''
    #######
    #@ $ .#
    #######''')                                # {'solved': True, 'actions': [...], ...}
    agent.replay(board_text, record["actions"])  # the boards of the real game along them
    agent.play(bouts=5)                          # its first 5 evaluation levels: 1.0 solved, 0.0 not
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from wmthesis.agents import TrainedAgent


class SearchMind:
    """The search agent as a mind for :func:`wmthesis.core.loop` (pass it as a callback too):
    it searches from the state it sees, follows the plan while the game shows what the model
    predicted, and searches again where it does not."""

    def __init__(self, agent, env):
        self.agent, self.env, self.plan_left = agent, env, []

    def plan(self, observation, train_mode: bool = True, debug_mode: bool = False):
        from wmthesis.sokoban_search.search import best_first

        state = self.agent.inputs.observe(self.env.unwrapped, observation)
        if not self.plan_left or not np.array_equal(self.plan_left[0][1], state):
            heuristic = self.agent.heuristic
            result = best_first(self.agent.model.expand, state, heuristic=heuristic, budget=self.agent.budget,
                                batch=self.agent.batch, weight=self.agent.weights[0], doubt=self.agent.doubt)
            self.plan_left = [] if result.actions is None else list(zip(result.actions, result.states[:-1]))
        scores = np.zeros(self.env.action_space.n)
        scores[self.plan_left.pop(0)[0] if self.plan_left else 0] = 1.0
        return scores

    def on_episode_start(self, episode, train_mode):
        self.plan_left = []

    def on_step_taken(self, step, transition, info):
        pass

    def on_action_planned(self, step, scores, info):
        pass

    def on_loop_start(self):
        pass

    def on_loop_end(self, is_aborted):
        pass

    def on_episode_end(self, episode, train_mode):
        pass

    metrics = {}


class SokobanAgent(TrainedAgent):
    """sokoban-search's pixel agent: ``model`` (the learned model over cells), ``value`` (the
    learned steps-to-go), ``search`` (the :class:`~wmthesis.sokoban_search.agent.SearchAgent`
    with its evaluation budget)."""

    def __init__(self, path: Path, experiment: str, variant: str | None, profile: str, seed: int):
        from wmthesis.config import for_profile
        from wmthesis.sokoban_search.config import SokobanSearchConfig
        from wmthesis.sokoban_search.iteration import evaluation_search, load_run

        cfg = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels")
        run = load_run(Path(path).parent, cfg)
        super().__init__(path, experiment, variant, profile, seed, {"history": run.history, "rounds": run.rounds_done})
        self.run, self.model, self.value, self.game = run, run.model, run.heuristic, "sokoban"
        self.search = run.agent(evaluation_search(cfg))

    def env(self):
        """Boxoban-sized levels (10x10, 4 boxes, 120 steps) of the generator, showing pixels."""
        return self.search.env("sokoban")

    def mind(self) -> SearchMind:
        return SearchMind(self.search, self.env())

    def scored_seeds(self, bouts: int) -> list[int]:
        from wmthesis.sokoban_search.agent import EVAL_PURPOSE, level_seeds

        return [int(s) for s in level_seeds(self.seed, EVAL_PURPOSE, bouts)]

    video_scale, fps = 1, 8

    def play_bouts(self, bouts: int, frames: list | None = None, on_bout=None) -> list[dict]:
        """The first ``bouts`` evaluation levels: each play's record (``seed``, ``solved``,
        ``actions``, ...) with its ``bout`` and ``return`` (1.0 solved, 0.0 not); ``frames`` gets
        each play replayed in the real game, its boards rendered."""
        env, plays = self.env(), []
        for k, level in enumerate(self.scored_seeds(bouts)):
            record = self.search.play(env, level).record()
            plays.append({"bout": k, "return": float(record["solved"]), **record})
            if frames is not None:
                frames.append(replayed_boards(record))
            if on_bout is not None:
                on_bout(plays[-1])
        return plays

    def record_bouts(self, bouts: int, recorder, plays: list, on_bout=None) -> None:
        """The evaluation levels played as :meth:`play_bouts` plays them, then replayed in the real
        game step by step beside what the agent planned: at each step the plan it follows (its
        player's path drawn on the board), the model's predicted boards along it ``horizon``
        steps ahead, and at each decision the search's size and the plan's length."""
        env = self.env()
        for k, level in enumerate(self.scored_seeds(bouts)):
            searches: dict[int, object] = {}
            played = self.search.play(env, level, on_search=lambda step, result: searches.__setitem__(step, result))
            record = played.record()
            frames, rewards = replayed_boards(record), played.transitions["rewards"]
            recorder.start_bout(k)
            plan = None
            for t, frame in enumerate(frames[:-1]):
                if t in searches:
                    plan = (t, searches[t])
                recorder.step(frame, self.plan_thought(plan, t, t in searches))
                recorder.outcome(float(rewards[t]))
            recorder.end_bout(frames[-1])
            plays.append({"bout": k, "return": float(record["solved"]), **record})
            if on_bout is not None:
                on_bout(plays[-1])

    def plan_thought(self, plan, t: int, decided: bool):
        """What the agent thinks at step ``t`` of the plan it follows (``(step it was found,
        SearchResult)``, or None): the rest of the plan as the player's path on the board, the
        boards its model predicts ``1..horizon`` steps ahead; the search's size and the plan's
        length where it ``decided`` at this step."""
        from wmthesis.envs.levels import PLAYER, PLAYER_ON_TARGET
        from wmthesis.envs.sokoban import make_tiles, render_board
        from wmthesis.thoughts import Thought

        if plan is None:
            return Thought()
        start, result = plan
        thought = Thought()
        if decided:
            thought.values = {"expanded": float(result.expanded), "generated": float(result.generated),
                              "plan_length": float(len(result.actions) if result.actions is not None else 0)}
        if result.states is None:
            return thought
        boards = self.boards(result.states[t - start:])
        path = [np.argwhere((b == PLAYER) | (b == PLAYER_ON_TARGET)) for b in boards]
        tile, tiles = 16, make_tiles(16)  # as the real game renders them (replayed_boards)
        thought.plan = np.asarray([((p[0, 1] + 0.5) * tile, (p[0, 0] + 0.5) * tile) for p in path if len(p)], np.float32)
        thought.imagined = {j: render_board(boards[j], tiles) for j in range(1, min(self.horizon, len(boards) - 1) + 1)}
        return thought

    def boards(self, states: np.ndarray) -> np.ndarray:
        """The model's states (n, h', w') (its codes per inner cell) as boards (n, h' + 2, w' + 2)
        of cell types inside their ring of walls; a code that is no cell type's shows as floor."""
        from wmthesis.envs.levels import FLOOR

        types = np.full(256, FLOOR, np.uint8)
        types[self.search.inputs.type_codes()] = np.arange(len(self.search.inputs.type_codes()), dtype=np.uint8)
        return np.pad(types[np.asarray(states)], ((0, 0), (1, 1), (1, 1)))

    def bout_line(self, play: dict) -> str:
        return (f"level {play['bout']} (seed {play['seed']}): {'solved' if play['solved'] else 'not solved'} "
                f"in {play['steps']} steps")

    def score_line(self, plays: list[dict]) -> str:
        solved = sum(p["solved"] for p in plays)
        return f"{solved} of {len(plays)} solved ({100 * solved / len(plays):.1f}%)"

    def solve(self, board, max_steps: int = 120) -> dict:
        """Play one level given as text (# wall, space floor, . target, $ box, * box on target,
        @ player, + player on target) or codes (h, w): ``solved``, ``steps``, ``actions``,
        ``expanded``, ... (:meth:`~wmthesis.sokoban_search.agent.Play.record`)."""
        from wmthesis.sokoban_search.evaluation import solve_boards

        return solve_boards(self.search, [as_board(board)], max_steps=max_steps, progress=False)[0]

    def replay(self, board, actions, max_steps: int = 120) -> dict:
        """``actions`` played on ``board`` in the package's real environment: its ``frames``
        (T + 1, H, W, 3) uint8 and whether they ``solved`` it."""
        from wmthesis.envs.actions import check_actions
        from wmthesis.sokoban_search.evaluation import board_env

        board = as_board(board)
        env = board_env(board, max_steps, observation="rgb")
        actions = check_actions(np.asarray(actions, dtype=None if len(actions) else np.int64), env.action_space.n,
                                len(actions))
        frame, _ = env.reset(options={"board": board})
        frames, solved = [frame], False
        for action in actions:
            frame, _, solved, truncated, _ = env.step(int(action))
            frames.append(frame)
            if solved or truncated:
                break
        return {"frames": np.stack(frames), "solved": bool(solved)}


    def predict(self, board, action: int) -> dict:
        """The learned model's step from ``board`` (as :meth:`solve` takes it) under ``action``: the
        ``frame`` it predicts (the cells' codes drawn back, (h*t, w*t, 3) uint8, the wall ring
        cropped, as the model sees frames), beside the real ``truth`` frame, and the ``reward`` and
        ``done`` it predicts."""
        from wmthesis.envs.actions import check_actions
        from wmthesis.sokoban_search.cells import crop_ring
        from wmthesis.sokoban_search.evaluation import board_env

        board, inputs = as_board(board), self.search.inputs
        env = board_env(board, 1, **inputs.env_options)
        (action,) = check_actions(np.asarray([action]), env.action_space.n, 1)
        observation, _ = env.reset(options={"board": board})
        codes, reward, done = self.search.model.step(inputs.observe(env.unwrapped, observation)[None], [action])
        truth = crop_ring(env.step(int(action))[0], inputs.coder.tile_size)
        return {"frame": inputs.coder.decode(codes)[0], "truth": truth, "reward": float(reward[0]), "done": bool(done[0])}


def replayed_boards(record: dict) -> np.ndarray:
    """A generated level's play (its ``seed`` and ``actions``) replayed in the real game, its boards
    rendered: (T + 1, H, W, 3) uint8."""
    from wmthesis.sokoban_search.agent import grid_env

    env = grid_env("sokoban")
    env.reset(seed=int(record["seed"]))
    frames = [env.render()]
    for action in record["actions"]:
        *_, terminated, truncated, _ = env.step(int(action))
        frames.append(env.render())
        if terminated or truncated:
            break
    return np.stack(frames)


def as_board(board) -> np.ndarray:
    """A level's text or its codes -> codes (h, w) uint8, checked."""
    from wmthesis.envs.levels import check_board, parse_level

    if isinstance(board, str):
        return parse_level(board)
    board = np.asarray(board, np.uint8)
    check_board(board)
    return board


def load_trained(path: Path, *, experiment: str, variant: str | None, profile: str, seed: int) -> SokobanAgent:
    return SokobanAgent(path, experiment, variant, profile, seed)


__all__ = ["SokobanAgent", "SearchMind", "load_trained", "as_board"]
