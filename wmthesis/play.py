"""Watch a trained agent play, without training: ``python -m wmthesis play EXPERIMENT ...``.

The agent is the one a ``quick`` run shipped in the repository (or one trained here), on the
experiment's own evaluation levels or bouts, so its results are the summary's seed row. Each
play's result is printed as it ends; ``record`` writes a rerun recording of the plays, ``video``
an mp4 of their frames (opencv). Paths are checked before anything plays; an agent that is not
there is one line naming what is missing and the command that trains it.

Agents that play today: ``sokoban-search`` (its shipped pixel agents, seeds 0-2 of ``quick``),
``boxing-wm`` (a run's ``agent-VARIANT.pt``: vision, memory and controller,
:mod:`wmthesis.world_models.agent`) on the bouts its summary row was scored on,
``boxing-wm-alphazero`` (a variant's ``agent-VARIANT.pt``: vision, memory, the search's heads,
:mod:`wmthesis.alphazero.agent`) searching on its evaluation games, and
every PlaNet experiment (a run's ``agent.pt``: PlaNet's model, and the value with CEM ending in it
where it has one, :mod:`wmthesis.planet.agent_file`) on the bouts its score was measured on.
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from wmthesis.config import EXPERIMENTS, profile_name
from wmthesis.utils import check_choice
from wmthesis.variants import no_variant

PLANET_AGENTS = ("planet-sokoban", "planet-boxing", "planet-freeway", "planet-boxing-agent", "planet-boxing-value",
                 "planet-freeway-value")  # each run writes its agent.pt (wmthesis.planet.agent_file)
PLAYABLE = ("sokoban-search", "boxing-wm", "boxing-wm-alphazero", *PLANET_AGENTS)


def check_output(path: str | os.PathLike | None, suffix: str) -> Path | None:
    """``path`` for a recording or video if it can be written (a file ending in ``suffix`` in a
    folder that exists and is writable); ValueError naming it otherwise, before anything plays."""
    if path is None:
        return None
    path = Path(path)
    if path.suffix != suffix:
        raise ValueError(f"{path}: name a {suffix} file")
    if path.is_dir() or not path.parent.is_dir() or not os.access(path.parent, os.W_OK):
        raise ValueError(f"{path} cannot be written: its folder {path.parent} is missing or not writable")
    return path


def play(experiment: str, *, profile: str | None = None, seed: int = 0, variant: str | None = None, bouts: int = 10,
         record=None, video=None, on_play=print) -> dict:
    """``bouts`` plays of ``experiment``'s trained agent (``seed``'s run of ``profile``; ``variant``:
    one of its variants, None the default); returns ``plays`` (one dict each) and ``score`` (their
    mean: the solve rate for Sokoban)."""
    check_choice("experiment", experiment, EXPERIMENTS)
    if experiment not in PLAYABLE:
        raise ValueError(f"play shows {', '.join(PLAYABLE)}; {experiment} has no agent that plays")
    if bouts < 1:
        raise ValueError(f"--bouts must be 1 or more, got {bouts}")
    record, video = check_output(record, ".rrd"), check_output(video, ".mp4")
    if experiment == "boxing-wm":
        return _play_boxing(profile_name(profile), seed, variant, bouts, record, video, on_play)
    if experiment == "boxing-wm-alphazero":
        return _play_alphazero(profile_name(profile), seed, variant, bouts, record, video, on_play)
    if experiment in PLANET_AGENTS:
        return _play_planet(experiment, profile_name(profile), seed, variant, bouts, record, video, on_play)
    no_variant(experiment, variant)
    return _play_sokoban(profile_name(profile), seed, bouts, record, video, on_play)


def _play_boxing(profile: str, seed: int, variant: str | None, bouts: int, record: Path | None, video: Path | None,
                 on_play) -> dict:
    """The World Models agent of ``boxing-wm`` on the first ``bouts`` of the bouts its score was
    measured on (:func:`~wmthesis.world_models.evolution.final_bout_seeds`), all at once."""
    from wmthesis.envs.vector import make_game
    from wmthesis.runs import work_folder
    from wmthesis.world_models.agent import load_agent
    from wmthesis.world_models.evolution import evaluate_population, final_bout_seeds
    from wmthesis.world_models.variants import BOXING_WM, agent_path

    name = BOXING_WM.check(variant).name
    path = agent_path(work_folder(profile, "boxing-wm", seed), name)
    if not path.is_file():
        raise FileNotFoundError(f"no trained boxing-wm agent at {path}: train it with `python -m wmthesis reproduce "
                                f"boxing-wm --profile {profile} --seed {seed}" + (f" --variant {variant}`" if variant else "`"))
    agent = load_agent(path)
    cfg = agent.info["controller_config"]
    game, shown = make_game("boxing", bouts, noop_max=cfg["noop_max"]), [] if record or video else None
    try:
        returns, steps = evaluate_population(agent.params[None], game, agent.vision, agent.memory,
                                             seeds=final_bout_seeds(bouts), max_steps=cfg["max_steps"], frames=shown)
    finally:
        game.close()
    plays = [{"bout": k, "return": float(r), "steps": int(n)} for k, (r, n) in enumerate(zip(returns[0], steps[0]))]
    for p in plays:
        on_play(f"bout {p['bout']}: {p['return']:+.0f} in {p['steps']} steps")
    score = float(np.mean(returns))
    on_play(f"mean {score:.1f} over {bouts} bout{'s' if bouts > 1 else ''} ({name}, {profile}, seed {seed})")
    if shown:
        _keep_frames(np.concatenate([np.stack([f[k] for f in shown[:p["steps"] + 1]]) for k, p in enumerate(plays)]),
                     record, video, fps=15)
    return {"experiment": "boxing-wm", "variant": name, "profile": profile, "seed": seed, "plays": plays,
            "score": score}


def _play_alphazero(profile: str, seed: int, variant: str | None, bouts: int, record: Path | None,
                    video: Path | None, on_play) -> dict:
    """The World Models + AlphaZero agent of ``variant`` (None: the default) searching on the first
    ``bouts`` of its evaluation games (:func:`~wmthesis.alphazero.evaluation.evaluation_seeds`)."""
    from wmthesis.alphazero.agent import agent_name, load_agent
    from wmthesis.alphazero.evaluation import evaluation_seeds
    from wmthesis.alphazero.selfplay import play as play_game
    from wmthesis.alphazero.variants import VARIANTS
    from wmthesis.envs.atari import boxing_env
    from wmthesis.runs import work_folder

    name = VARIANTS.check(variant).name
    path = work_folder(profile, "boxing-wm-alphazero", seed) / agent_name(name)
    if not path.is_file():
        raise FileNotFoundError(f"no trained boxing-wm-alphazero agent at {path}: train it with `python -m wmthesis "
                                f"reproduce boxing-wm-alphazero --profile {profile} --seed {seed} --variant {name}`")
    agent = load_agent(path)
    mind, env, plays, frames = agent.mind(), boxing_env(agent.config.noop_max), [], []
    try:
        for k, game_seed in enumerate(evaluation_seeds(seed, bouts, agent.config.noop_max)):
            mind.keep_frames = bool(record or video)
            game = play_game(env, mind, game_seed, k, train_mode=False, max_steps=agent.config.eval_max_steps)
            plays.append({"bout": k, "return": float(game.score), "steps": len(game.actions)})
            frames += [] if game.frames is None else list(game.frames)
            on_play(f"bout {k}: {game.score:+.0f} in {len(game.actions)} steps")
    finally:
        env.close()
    score = float(np.mean([p["return"] for p in plays]))
    on_play(f"mean {score:.1f} over {bouts} bout{'s' if bouts > 1 else ''} ({name}, {profile}, seed {seed}, "
            f"{agent.config.simulations} simulations an action)")
    _keep_frames(np.stack(frames) if frames else None, record, video, fps=15)
    return {"experiment": "boxing-wm-alphazero", "variant": name, "profile": profile, "seed": seed, "plays": plays,
            "score": score}


def _play_planet(experiment: str, profile: str, seed: int, variant: str | None, bouts: int, record: Path | None,
                 video: Path | None, on_play) -> dict:
    """The PlaNet agent of ``experiment``'s ``variant`` (None: the default; with a learned value
    where the experiment fits one) on the first ``bouts`` of the bouts its score was measured on."""
    from wmthesis.experiments import VARIANTS
    from wmthesis.planet.agent_file import AGENT_NAME, load_agent, play_agent
    from wmthesis.runs import work_folder

    if experiment in VARIANTS:
        name, folder = VARIANTS[experiment].check(variant).name, VARIANTS[experiment].folder_name(variant)
    else:
        no_variant(experiment, variant)
        name = folder = None
    path = work_folder(profile, experiment, seed, folder) / AGENT_NAME
    if not path.is_file():
        raise FileNotFoundError(f"no trained {experiment} agent at {path}: train it with `python -m wmthesis reproduce "
                                f"{experiment} --profile {profile} --seed {seed}" + (f" --variant {name}`" if name else "`"))
    agent = load_agent(path)
    plays, frames = [], [] if record or video else None
    for k, (env_seed, mind_seed) in enumerate(agent.info["bouts"][:bouts]):
        rewards = play_agent(agent, env_seed, mind_seed, frames)
        plays.append({"bout": k, "return": float(sum(rewards)), "steps": len(rewards)})
        on_play(f"bout {k}: {plays[-1]['return']:+.0f} in {len(rewards)} steps")
    score = float(np.mean([p["return"] for p in plays]))
    on_play(f"mean {score:.1f} over {len(plays)} bout{'s' if len(plays) > 1 else ''} ({name or experiment}, {profile}, "
            f"seed {seed})")
    _keep_frames(np.stack(frames) if frames else None, record, video, fps=15)
    return {"experiment": experiment, "variant": name, "profile": profile, "seed": seed, "plays": plays, "score": score}


def _keep_frames(frames: np.ndarray | None, record: Path | None, video: Path | None, fps: int) -> None:
    """``frames`` (T, H, W, 3) uint8 as a rerun recording and an mp4 (4x larger), where asked for."""
    if frames is None:
        return
    if record is not None:
        from wmthesis.viz import record_frames

        record_frames(record, {"frame": frames})
    if video is not None:
        _write_video(video, np.repeat(np.repeat(frames, 4, axis=1), 4, axis=2), fps=fps)


def _play_sokoban(profile: str, seed: int, levels: int, record: Path | None, video: Path | None, on_play) -> dict:
    """The pixel agent of ``sokoban-search`` on the first ``levels`` of its unseen 10x10 evaluation levels."""
    from wmthesis.experiments.sokoban_search import EVAL_PURPOSE, work_folder
    from wmthesis.sokoban_search.agent import level_seeds
    from wmthesis.sokoban_search.config import SokobanSearchConfig
    from wmthesis.config import for_profile
    from wmthesis.sokoban_search.iteration import evaluation_search, load_run

    folder = work_folder(profile, seed) / "pixels"
    cfg = for_profile(SokobanSearchConfig, profile, seed=seed, inputs="pixels")
    run = load_run(folder, cfg)
    if run is None:
        raise FileNotFoundError(f"no trained sokoban-search agent in {folder}: train it with `python -m wmthesis "
                                f"reproduce sokoban-search --profile {profile} --seed {seed}`")
    agent = run.agent(evaluation_search(cfg))
    env = agent.env("sokoban")
    plays = []
    for k, level in enumerate(level_seeds(seed, EVAL_PURPOSE, levels)):
        played = agent.play(env, level).record()
        plays.append(played)
        on_play(f"level {k} (seed {level}): {'solved' if played['solved'] else 'not solved'} in {played['steps']} steps")
    score = float(np.mean([p["solved"] for p in plays]))
    on_play(f"{sum(p['solved'] for p in plays)} of {levels} solved ({100 * score:.1f}%)")
    if record is not None or video is not None:
        frames = _sokoban_frames(plays)
        if record is not None:
            from wmthesis.viz import record_frames

            record_frames(record, {"board": frames})
        if video is not None:
            _write_video(video, frames)
    return {"experiment": "sokoban-search", "profile": profile, "seed": seed, "plays": plays, "score": score}


def _sokoban_frames(plays: list[dict]) -> np.ndarray:
    """Every play replayed in the real game, its boards rendered: (T, H, W, 3) uint8."""
    from wmthesis.sokoban_search.agent import grid_env

    env, frames = grid_env("sokoban"), []
    for played in plays:
        env.reset(seed=int(played["seed"]))
        frames.append(env.render())
        for action in played["actions"]:
            *_, terminated, truncated, _ = env.step(int(action))
            frames.append(env.render())
            if terminated or truncated:
                break
    return np.stack(frames)


def _write_video(path: Path, frames: np.ndarray, fps: int = 8) -> None:
    """``frames`` (T, H, W, 3) RGB as an mp4 at ``path``."""
    import cv2

    height, width = frames.shape[1:3]
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"mp4v"), fps, (width, height))
    try:
        for frame in frames:
            writer.write(cv2.cvtColor(frame, cv2.COLOR_RGB2BGR))
    finally:
        writer.release()


__all__ = ["PLAYABLE", "check_output", "play"]
