"""Evaluation games shared by every agent compared on Boxing (thesis 5.4.2): the same seeded
no-op starts for each, greedy play, returns; the trained heads with and without search, random
play and the World Models controller on them, each cached; the scores as a figure."""
from __future__ import annotations

import pickle
import time
from pathlib import Path
from typing import Callable

import matplotlib.pyplot as plt
from tqdm.auto import tqdm

from wmthesis.alphazero.heads import Evaluator
from wmthesis.alphazero.imitation import PolicyHeadMind
from wmthesis.alphazero.replay import game_seeds
from wmthesis.alphazero.selfplay import AlphaZeroMind, play
from wmthesis.config import for_profile
from wmthesis.core import Mind, RandomMind, loop
from wmthesis.envs.atari import boxing_env, noop_count
from wmthesis.references import human, random_play
from wmthesis.runs import atomic_path, read_json, write_json
from wmthesis.training import load_weights
from wmthesis.utils import check_choice, derive_seeds, fingerprint, read_pickle
from wmthesis.world_models.config import MemoryConfig
from wmthesis.world_models.controller import ControllerMind
from wmthesis.world_models.evolution import load_run
from wmthesis.world_models.train import make_memory
from wmthesis.world_models.variants import controller_folder


def evaluation_seeds(seed: int, episodes: int, noop_max: int = 30) -> list[int]:
    """The seed of each evaluation game, shared by every agent compared (through
    :func:`~wmthesis.alphazero.replay.game_seeds`: the same no-op starts). Seeds whose no-op
    count repeats an earlier game's are skipped: Boxing is deterministic, so a greedy agent
    would replay the same game."""
    return _new_count_seeds(seed, 3, episodes, noop_max, set())


def validation_seeds(seed: int, episodes: int, noop_max: int = 30, reserved: int = 10) -> list[int]:
    """Seeds of games to choose a recipe on: each with a no-op count of its own that none of the
    first ``reserved`` :func:`evaluation_seeds` uses (Boxing is deterministic, so a game is its
    no-op count: a choice made on these never sees a reported bout). ValueError where fewer than
    ``episodes`` counts are left."""
    taken = {noop_count(game_seeds(s)[0], noop_max) for s in evaluation_seeds(seed, reserved, noop_max)}
    if episodes > max(noop_max, 1) - len(taken):
        raise ValueError(f"{episodes} validation games need {episodes} no-op counts apart from the evaluation's "
                         f"{len(taken)}; there are {max(noop_max, 1)}")
    return _new_count_seeds(seed, 10, episodes, noop_max, taken)


def _new_count_seeds(seed: int, stream: int, episodes: int, noop_max: int, taken: set) -> list[int]:
    """``episodes`` game seeds drawn from ``(seed, stream, k)``, k = 0, 1, ..., each kept only where
    its no-op count is not in ``taken`` (which it joins), until every count is taken: then repeats."""
    seeds, k = [], 0
    while len(seeds) < episodes:
        game_seed = int(derive_seeds(seed, stream, k)[0])
        count = noop_count(game_seeds(game_seed)[0], noop_max)
        if count not in taken or len(taken) >= max(noop_max, 1):
            seeds.append(game_seed)
            taken.add(count)
        k += 1
    return seeds


def greedy_returns(env, make_mind: Callable[[int], Mind], seeds, *, max_steps: int | None,
                   as_callback: bool = True, steps: list | None = None) -> list[float]:
    """The return of one greedy game per seed in ``seeds``: the env is reset with the first of
    :func:`~wmthesis.alphazero.replay.game_seeds` and ``make_mind`` gets the second (the
    agent's own seed). ``as_callback``: the mind also follows each step (a mind with a memory);
    ``steps`` (a list) gets each game's number of steps."""
    returns = []
    for game_seed in seeds:
        env_seed, agent_seed = game_seeds(game_seed)
        mind = make_mind(agent_seed)
        history = loop(env, mind, policy="deterministic", callbacks=[mind] if as_callback else None,
                       max_steps=max_steps, seed=env_seed, train_mode=False)
        returns.append(float(history[0]["return"]))
        if steps is not None:
            steps.append(int(history[0]["steps"]))
    return returns


RECORDING_STEPS = 400  # the rerun recording shows the first steps of one evaluation game


BOUTS = ("evaluation", "validation")


def bout_seeds(split: str, seed: int, episodes: int, noop_max: int) -> list[int]:
    """The seeds of ``episodes`` games of ``split``: :func:`evaluation_seeds`, or
    :func:`validation_seeds` apart from the first 10 evaluation games' no-op counts (fewer where
    the counts run out: smoke's 3 counts leave one validation game beside 2 evaluation games)."""
    check_choice("bouts", split, BOUTS)
    if split == "evaluation":
        return evaluation_seeds(seed, episodes, noop_max)
    reserved = min(10, max(noop_max, 1) - 1)
    return validation_seeds(seed, min(episodes, max(noop_max, 1) - reserved), noop_max, reserved)


def evaluation_games(run, vision, memory, cfg, work: Path, seed: int, pretrained: bool = False) -> list:
    """``cfg.eval_episodes`` greedy games of the trained heads (the first keeps its frames);
    cached in ``evaluation.pkl`` for the run's number of games. ``pretrained``: the heads
    after imitation, before self-play (``evaluation-pretrained.pkl``). A search deciding by
    ``decision_beta`` B keeps its games apart (``...-beta-B.pkl``). Each game is saved as it ends
    (``*.partial.pkl``): a cut-off evaluation plays only the rest. (Other budgets and roots, and
    validation games: :mod:`wmthesis.alphazero.budget`.)"""
    name = "evaluation-pretrained.pkl" if pretrained else "evaluation.pkl"
    if cfg.decision_beta is not None:
        name = name.replace(".pkl", f"-beta-{cfg.decision_beta:g}.pkl")
    path = work / name
    key = {"games": 0 if pretrained else run.games, "episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps,
           "seeds": evaluation_seeds(seed, cfg.eval_episodes, cfg.noop_max),
           **({} if cfg.decision_beta is None else {"decision_beta": cfg.decision_beta})}
    cached = cached_games(path, key)  # a missing or corrupt cache is played again
    if cached is not None:
        return cached
    heads = run.pretrained_heads() if pretrained else run.heads
    mind = AlphaZeroMind(vision, run.mdp(memory), Evaluator(heads), cfg)
    return resumed_games(path, key, mind, boxing_env(cfg.noop_max), keep_frames=True)


def resumed_games(path: Path, key: dict, mind, env, keep_frames: bool = False, progress: bool = False,
                  desc: str = "bouts") -> list:
    """One greedy game of ``mind`` in ``env`` per seed of ``key["seeds"]`` (of ``key["max_steps"]``),
    each saved as it ends (``*.partial.pkl``: a cut-off run plays only the rest), then all in
    ``path`` under ``key``; ``keep_frames``: the first game keeps its first frames. Closes ``env``."""
    partial = path.with_name(path.stem + ".partial.pkl")
    games = cached_games(partial, key) or []
    try:
        for k, game_seed in tqdm(list(enumerate(key["seeds"]))[len(games):], desc=desc, unit="bout", disable=not progress):
            mind.keep_frames = keep_frames and k == 0
            game = play(env, mind, game_seed, k, train_mode=False, max_steps=key["max_steps"])
            if game.frames is not None:
                game.frames = game.frames[:RECORDING_STEPS]
            games.append(game)
            save_games(partial, key, games)
    finally:
        env.close()
    save_games(path, key, games)
    partial.unlink(missing_ok=True)
    return games


def cached_games(path: Path, key: dict) -> list | None:
    """The games saved in ``path`` under ``key``; None where missing, corrupt or of another key."""
    try:
        cached = read_pickle(path)
        return cached["games"] if cached["key"] == key else None
    except (OSError, ValueError):  # read_pickle names a corrupt file in a ValueError
        return None


def save_games(path: Path, key: dict, games: list) -> None:
    """``games`` under ``key`` in ``path``, atomically (what :func:`cached_games` reads)."""
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        pickle.dump({"key": key, "games": games}, f)


def policy_head_games(run, vision, memory, cfg, work: Path, seed: int) -> dict:
    """The trained policy head played greedily without search on ``cfg.eval_episodes`` evaluation
    games: ``returns`` and ``ms_per_action`` (:func:`head_returns`); cached in ``policy-head-N.json``
    for N games."""
    key = {"games": run.games, "episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps,
           "seeds": evaluation_seeds(seed, cfg.eval_episodes, cfg.noop_max)}
    path = work / f"policy-head-{cfg.eval_episodes}.json"
    cached = read_json(path)
    if cached is not None and cached["key"] == key:
        return cached
    result = {"key": key, **head_returns(vision, run.mdp(memory), run.heads, boxing_env(cfg.noop_max), key)}
    write_json(path, result)
    return result


def head_returns(vision, mdp, heads, env, key: dict) -> dict:
    """The policy head alone (no search) in one greedy game per seed of ``key["seeds"]`` (of
    ``key["max_steps"]``): ``returns`` and ``ms_per_action`` (the encoding, the head and the
    emulator together). Closes ``env``."""
    mind, steps = PolicyHeadMind(vision, mdp, heads), []
    start = time.perf_counter()
    try:
        returns = greedy_returns(env, lambda agent_seed: mind, key["seeds"], max_steps=key["max_steps"], steps=steps)
    finally:
        env.close()
    return {"returns": returns, "ms_per_action": 1000 * (time.perf_counter() - start) / max(1, sum(steps))}


def policy_head_returns(run, vision, memory, cfg, work: Path, seed: int) -> list[float]:
    """The evaluation games' returns of the trained policy head played greedily without search
    (how much the search adds to what the heads learned): :func:`policy_head_games`' returns."""
    return policy_head_games(run, vision, memory, cfg, work, seed)["returns"]


def controller_minds(profile: str, wm: Path, vision) -> tuple:
    """``(agent_seed -> ControllerMind, name)`` for the boxing-wm controller under `wm`, or
    ``(None, why not)`` when it is missing, still evolving or was trained on another memory: the default recipe's
    (:data:`~wmthesis.world_models.variants.BOXING_WM`)."""
    controller_path, memory_path = controller_folder(wm) / "controller.pkl", wm / "memory-mdn.best.pt"
    if not (controller_path.is_file() and memory_path.is_file()):
        return None, (f"no boxing-wm controller under {wm} (run notebook 02 / `reproduce boxing-wm` first): "
                      "the comparison with it is skipped")
    run = load_run(controller_path)
    if run.generation < run.config["generations"]:
        return None, (f"the boxing-wm controller under {wm} has evolved {run.generation} of its "
                      f"{run.config['generations']} generations (`reproduce boxing-wm` finishes it)")
    mdn = load_weights(memory_path, make_memory(16, 18, for_profile(MemoryConfig, profile))).eval()
    if fingerprint(mdn) != run.task["memory"]:
        return None, f"the controller in {controller_path.parent} was trained on another memory: skipped"
    controller = run.controller("mean")
    return (lambda agent_seed: ControllerMind(vision, mdn, controller)), \
        f"World Models controller (notebook 02, generation {run.generation})"


def boxing_baselines(profile: str, wm: Path, work: Path, vision, cfg, seed: int) -> dict:
    """Random play and the boxing-wm controller (when its run exists) on the evaluation games;
    cached in ``baselines.json``. Returns ``returns`` by agent and ``notes``."""
    controller_path = controller_folder(wm) / "controller.pkl"
    key = {"episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps,
           "seeds": evaluation_seeds(seed, cfg.eval_episodes, cfg.noop_max),
           "controller_mtime": controller_path.stat().st_mtime_ns if controller_path.is_file() else None}
    cached = read_json(work / "baselines.json")
    if cached is not None and cached["key"] == key:
        return cached
    minds, notes = {"random": lambda agent_seed: RandomMind(18, agent_seed)}, []
    make_controller, name = controller_minds(profile, wm, vision)
    if make_controller is None:
        notes.append(name)
    else:
        minds[name] = make_controller
    returns = {}
    env = boxing_env(cfg.noop_max)
    try:
        for name, make_mind in minds.items():
            returns[name] = greedy_returns(env, make_mind, key["seeds"], max_steps=cfg.eval_max_steps,
                                           as_callback=name != "random")
    finally:
        env.close()
    result = {"key": key, "returns": returns, "notes": notes}
    write_json(work / "baselines.json", result)
    return result


def score_figure(scores: dict):
    """Evaluation scores (mean +- std) of every agent, beside random and human play (published)."""
    fig, ax = plt.subplots(figsize=(6, 0.5 + 0.45 * len(scores)))
    names = list(scores)
    ax.barh(names, [scores[n]["mean"] for n in names], xerr=[scores[n]["std"] for n in names], capsize=3,
            color=[f"C{i}" for i in range(len(names))])
    for value, style, label in ((random_play("boxing"), "--", "random (published)"), (human("boxing"), ":", "human (published)")):
        ax.axvline(value, color="0.4", ls=style, lw=1, label=label)
    ax.invert_yaxis()
    ax.set_xlabel("Boxing score (mean ± std)")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0))  # beside the bars, over none
    fig.tight_layout()
    return fig
