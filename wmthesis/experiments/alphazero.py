"""World Models + AlphaZero on Boxing (thesis 5.4.2), and why the thesis's version fails."""
from __future__ import annotations

import json
import time
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np

from wmthesis.alphazero.evaluation import evaluation_seeds, greedy_returns
from wmthesis.config import CollectConfig, MemoryConfig, VisionConfig, for_profile, profile_name
from wmthesis.runs import first_run_seconds, read_json, run_header
from wmthesis.utils import data_dir, read_pickle
from wmthesis.runs import atomic_path, hold, releasing_holds
from wmthesis.references import human, published, random_play
from wmthesis.viz import save_figure

ALPHAZERO_DIAGNOSIS_DEPTH = {"smoke": 5, "quick": 10, "thesis": 10}
RECORDING_STEPS = 400  # the rerun recording shows the first steps of one evaluation game


@releasing_holds
def boxing_wm_alphazero(profile: str | None = None, seed: int = 0, variant: str | None = None,
                        progress: bool = True) -> dict:
    """Thesis 5.4.2: World Models + AlphaZero on Boxing, and why the thesis's version fails.

    Reuses the boxing-wm pipeline's random rollouts, vision and latents (the same artifacts
    under ``data/<profile>/boxing-wm/seed<seed>/``, cached), trains a deterministic memory in
    its own folder ``data/<profile>/boxing-wm-alphazero/seed<seed>/``, then self-play for each
    variant of :data:`~wmthesis.alphazero.selfplay.VARIANTS` (``variant=None``: all of them, side
    by side; one name: that one only), each resumable from its checkpoint. Every variant, the
    boxing-wm controller (when its run exists) and random play then play the same greedy
    evaluation games (same no-op starts). Diagnosis: the memory's reward error along the search
    depth, whether a linear value on ``[z h]`` predicts the random rollouts' returns at all,
    whether an MLP on ``[z h a]`` can tell which action earns more in the next steps
    (:func:`~wmthesis.alphazero.diagnosis.action_predictability`), the value scale, the spread of
    root Q, ties and the actions taken. The ``learned-reward`` variant trains its reward model on
    the same random rollouts (and its self-play games).

    The ``imitation`` variant imitates notebook 02's controller (trained first if missing); it
    is also evaluated by its policy head alone, without search, and with its heads as they
    were before self-play.

    Results under ``data/results/boxing-wm-alphazero/<profile>-seed<seed>/`` (one variant: in
    its subfolder): figures, a rerun recording of an evaluation game, ``metrics.json``. Returns
    the metrics; ``score`` is the last variant's (``imitation`` when all run);
    ``against_random``: each agent's mean minus random play's, with its standard error.
    """
    from wmthesis.alphazero.latent_mdp import LatentMDP
    from wmthesis.alphazero.selfplay import VARIANTS, train_alphazero
    from wmthesis.envs.atari import boxing_env
    from wmthesis.alphazero import diagnosis
    from wmthesis.world_models.vision import VAEVision
    from wmthesis.world_models.train import LatentStore, encode_store, train_memory, train_vision
    from wmthesis.config import AlphaZeroConfig
    from wmthesis.data import EpisodeStore, collect
    from wmthesis.metrics import score_difference, score_summary
    from wmthesis.viz import record_frames

    variants = tuple(VARIANTS) if variant is None else (VARIANTS.check(variant).name,)
    profile = profile_name(profile)
    started = time.time()
    wm = data_dir(profile, "boxing-wm", f"seed{seed}")
    work = hold(data_dir(profile, "boxing-wm-alphazero", f"seed{seed}"))
    out = data_dir("results", "boxing-wm-alphazero", f"{profile}-seed{seed}", *(() if variant is None else (variant,)))
    collect_cfg = for_profile(CollectConfig, profile)
    store = collect("boxing", collect_cfg.episodes, wm / "random.h5", workers=collect_cfg.workers, seed=seed,
                    preprocessing="world_models", max_steps=collect_cfg.max_steps, progress=progress)
    vae, _ = train_vision(store, wm, for_profile(VisionConfig, profile), seed=seed, progress=progress)
    latents = encode_store(store, vae, wm / "latents.h5", progress=progress)
    memory, memory_history = train_memory(latents, work, for_profile(MemoryConfig, profile, kind="deterministic"),
                                          n_actions=18, seed=seed, progress=progress)
    vision = VAEVision(vae)

    configs, runs, games, ablations = {}, {}, {}, {}
    for name in variants:
        configs[name] = cfg = for_profile(AlphaZeroConfig, profile, **VARIANTS.changes(name))
        expert = _expert(profile, seed, wm, vision, progress) if cfg.expert_games else None
        run = train_alphazero(lambda: boxing_env(cfg.noop_max), vision, memory, cfg, out_dir=work / name,
                                 seed=seed, progress=progress, rollouts=LatentStore(latents), expert=expert)
        runs[name] = run.summary()
        games[name] = _alphazero_evaluate(run, vision, memory, cfg, work / name, seed)
        if cfg.expert_games:
            ablations[f"AlphaZero {name}: policy head alone, no search"] = \
                _policy_head_returns(run, vision, memory, cfg, work / name, seed)
            if run.pretrained is not None:  # (checkpoints written before it was kept have none)
                pretrained = _alphazero_evaluate(run, vision, memory, cfg, work / name, seed, pretrained=True)
                ablations[f"AlphaZero {name}: before self-play (search)"] = [g.score for g in pretrained]
    cfg = configs[variants[-1]]
    baselines = _boxing_baselines(profile, wm, work, vision, cfg, seed)
    with EpisodeStore(store) as episodes:  # random play over the self-play games' length, for the curve
        random_in_store = [float(episodes.episode(i)["rewards"][:cfg.max_steps].sum()) for i in range(len(episodes))]

    mdp = LatentMDP(memory)
    all_games = [game for name in variants for game in games[name]]
    depth = ALPHAZERO_DIAGNOSIS_DEPTH[profile]
    reward_error = diagnosis.reward_error_by_depth(mdp, all_games, depth)
    value_fit = diagnosis.value_predictability(mdp, LatentStore(latents), cfg.gamma, cfg.n_step)
    action_fit = diagnosis.action_predictability(mdp, LatentStore(latents), seed=seed)
    search = {name: diagnosis.search_statistics(games[name], cfg.gamma, cfg.c, cfg.simulations) for name in variants}
    figures = [
        save_figure(diagnosis.plot_self_play(runs, {f"random play, first {cfg.max_steps or 'all'} steps (store)":
                                       float(np.mean(random_in_store))}), out / "self_play_curve.png"),
        save_figure(diagnosis.plot_search(games, cfg.gamma, cfg.c, cfg.simulations), out / "search_statistics.png"),
        save_figure(diagnosis.plot_reward_error(reward_error, np.concatenate([g.depths for g in all_games])),
              out / "reward_error_by_depth.png"),
        save_figure(diagnosis.plot_visits(games[variants[-1]][0]), out / "visit_distributions.png"),
    ]
    returns = {**{f"AlphaZero {name}": [g.score for g in games[name]] for name in variants}, **ablations,
               **baselines["returns"]}
    scores = {name: score_summary(r) for name, r in returns.items()}
    against_random = {name: score_difference(r, returns["random"]) for name, r in returns.items() if name != "random"}
    figures.append(save_figure(_score_figure(scores), out / "scores.png"))
    shown = games[variants[-1]][0]
    recording = record_frames(out / "evaluation_game.rrd", {"observation": shown.frames},
                              {name: values[:RECORDING_STEPS] for name, values in
                               (("reward", shown.rewards), ("predicted_reward", shown.predicted_rewards),
                                ("root_value", shown.root_values))})
    metrics = {
        **run_header("boxing-wm-alphazero", profile, seed, time.time() - started, variants=list(variants)),
        "score": scores[f"AlphaZero {variants[-1]}"], "scores": scores, "against_random": against_random,
        "evaluation": {"episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps, "notes": baselines["notes"]},
        "random_play_in_store": {"max_steps": cfg.max_steps, **score_summary(random_in_store)},
        "reference": published("boxing-wm-alphazero"),
        "runs": runs,
        "diagnosis": {"reward_error": reward_error, "value_fit_on_random_rollouts": value_fit,
                      "action_fit_on_random_rollouts": action_fit, "search": {name: {
            "value_return_corr": s["value_return_corr"], "mean_abs_root_value": float(np.abs(s["root_value"]).mean()),
            "mean_abs_return": float(np.abs(s["returns"]).mean()), "median_q_spread": float(np.median(s["q_spread"])),
            "prior_bonus": s["prior_bonus"], "mean_visit_entropy": float(s["visit_entropy"].mean()),
            "top_count_tied": s["tied"],
            "noop_fraction": float(np.mean(np.concatenate([g.actions for g in games[name]]) == 0)),
            "median_search_depth": float(np.median(np.concatenate([g.depths for g in games[name]])))}
            for name, s in search.items()}},
        "memory_history": memory_history,
        "files": {"figures": [str(f) for f in figures], "recording": str(recording)},
    }
    metrics["first_run_wall_seconds"] = first_run_seconds(out / "metrics.json", metrics["wall_seconds"])
    with atomic_path(out / "metrics.json") as tmp:
        tmp.write_text(json.dumps(metrics, indent=1, default=float))
    return metrics


def _alphazero_evaluate(run, vision, memory, cfg, work: Path, seed: int, pretrained: bool = False) -> list:
    """``cfg.eval_episodes`` greedy games of the trained heads (the first keeps its frames);
    cached in ``evaluation.pkl`` for the run's number of games. ``pretrained``: the heads
    after imitation, before self-play (``evaluation-pretrained.pkl``)."""
    import pickle

    from wmthesis.alphazero.heads import Evaluator
    from wmthesis.alphazero.selfplay import AlphaZeroMind, play
    from wmthesis.envs.atari import boxing_env

    path = work / ("evaluation-pretrained.pkl" if pretrained else "evaluation.pkl")
    key = {"games": 0 if pretrained else run.games, "episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps,
           "seeds": evaluation_seeds(seed, cfg.eval_episodes, cfg.noop_max)}
    try:  # a missing or corrupt cache is played again
        cached = read_pickle(path)
        if cached["key"] == key:
            return cached["games"]
    except (OSError, ValueError):
        pass
    heads = run.pretrained_heads() if pretrained else run.heads
    mind = AlphaZeroMind(vision, run.mdp(memory), Evaluator(heads), cfg)
    env = boxing_env(cfg.noop_max)
    games = []
    try:
        for k, game_seed in enumerate(key["seeds"]):
            mind.keep_frames = k == 0
            game = play(env, mind, game_seed, k, train_mode=False, max_steps=cfg.eval_max_steps)
            if game.frames is not None:
                game.frames = game.frames[:RECORDING_STEPS]
            games.append(game)
    finally:
        env.close()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        pickle.dump({"key": key, "games": games}, f)
    return games


def _policy_head_returns(run, vision, memory, cfg, work: Path, seed: int) -> list[float]:
    """The evaluation games' returns of the trained policy head played greedily without search
    (how much the search adds to what the heads learned); cached in ``policy_head.json``."""
    from wmthesis.envs.atari import boxing_env
    from wmthesis.alphazero.imitation import PolicyHeadMind

    key = {"games": run.games, "episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps,
           "seeds": evaluation_seeds(seed, cfg.eval_episodes, cfg.noop_max)}
    cached = read_json(work / "policy_head.json")
    if cached is not None and cached["key"] == key:
        return cached["returns"]
    mind, env = PolicyHeadMind(vision, run.mdp(memory), run.heads), boxing_env(cfg.noop_max)
    try:
        returns = greedy_returns(env, lambda agent_seed: mind, key["seeds"], max_steps=cfg.eval_max_steps)
    finally:
        env.close()
    with atomic_path(work / "policy_head.json") as tmp:
        tmp.write_text(json.dumps({"key": key, "returns": returns}, indent=1))
    return returns


def _expert(profile: str, seed: int, wm: Path, vision, progress: bool):
    """``agent_seed -> ControllerMind``: notebook 02's controller (the CMA-ES mean) as the
    imitation variant's expert; trains it first (the cached boxing-wm pipeline) if it is missing."""
    from wmthesis.experiments.world_models import boxing_world_models

    make_mind, note = _controller_minds(profile, wm, vision)
    if make_mind is None:
        boxing_world_models(profile, seed, progress=progress)
        make_mind, note = _controller_minds(profile, wm, vision)
    if make_mind is None:
        raise RuntimeError(f"the imitation variant needs notebook 02's controller: {note}")
    return make_mind


def _controller_minds(profile: str, wm: Path, vision) -> tuple:
    """``(agent_seed -> ControllerMind, name)`` for the boxing-wm controller under `wm`, or
    ``(None, why not)`` when it is missing or was trained on another memory."""
    from wmthesis.world_models.controller import ControllerMind
    from wmthesis.utils import fingerprint
    from wmthesis.world_models.evolution import load_run
    from wmthesis.world_models.train import make_memory
    from wmthesis.training import load_weights

    controller_path, memory_path = wm / "controller" / "controller.pkl", wm / "memory-mdn.best.pt"
    if not (controller_path.is_file() and memory_path.is_file()):
        return None, (f"no boxing-wm controller under {wm} (run notebook 02 / `reproduce boxing-wm` first): "
                      "the comparison with it is skipped")
    run = load_run(controller_path)
    mdn = load_weights(memory_path, make_memory(16, 18, for_profile(MemoryConfig, profile))).eval()
    if fingerprint(mdn) != run.task["memory"]:
        return None, f"the controller in {controller_path.parent} was trained on another memory: skipped"
    controller = run.controller("mean")
    return (lambda agent_seed: ControllerMind(vision, mdn, controller)), \
        f"World Models controller (notebook 02, generation {run.generation})"


def _boxing_baselines(profile: str, wm: Path, work: Path, vision, cfg, seed: int) -> dict:
    """Random play and the boxing-wm controller (when its run exists) on the evaluation games;
    cached in ``baselines.json``. Returns ``returns`` by agent and ``notes``."""
    from wmthesis.envs.atari import boxing_env
    from wmthesis.core import RandomMind

    controller_path = wm / "controller" / "controller.pkl"
    key = {"episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps,
           "seeds": evaluation_seeds(seed, cfg.eval_episodes, cfg.noop_max),
           "controller_mtime": controller_path.stat().st_mtime_ns if controller_path.is_file() else None}
    cached = read_json(work / "baselines.json")
    if cached is not None and cached["key"] == key:
        return cached
    minds, notes = {"random": lambda agent_seed: RandomMind(18, agent_seed)}, []
    make_controller, name = _controller_minds(profile, wm, vision)
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
    with atomic_path(work / "baselines.json") as tmp:
        tmp.write_text(json.dumps(result, indent=1))
    return result


def _score_figure(scores: dict):
    """Evaluation scores (mean +- std) of every agent, beside random and human play (published)."""
    fig, ax = plt.subplots(figsize=(6, 0.5 + 0.45 * len(scores)))
    names = list(scores)
    ax.barh(names, [scores[n]["mean"] for n in names], xerr=[scores[n]["std"] for n in names], capsize=3,
            color=[f"C{i}" for i in range(len(names))])
    for value, style, label in ((random_play("boxing"), "--", "random (published)"), (human("boxing"), ":", "human (published)")):
        ax.axvline(value, color="0.4", ls=style, lw=1, label=label)
    ax.invert_yaxis()
    ax.set_xlabel("Boxing score (mean ± std)")
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig
