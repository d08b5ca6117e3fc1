"""World Models + AlphaZero on Boxing (thesis 5.4.2), and why the thesis's version fails."""
from __future__ import annotations

import dataclasses
import json
import time
from pathlib import Path

import numpy as np

from wmthesis.alphazero import diagnosis
from wmthesis.alphazero.agent import agent_name, save_agent
from wmthesis.alphazero.config import AlphaZeroConfig, DiagnosisConfig
from wmthesis.alphazero.evaluation import (RECORDING_STEPS, boxing_baselines, controller_minds, evaluation_games,
                                           policy_head_returns, score_figure)
from wmthesis.alphazero.expert_memory import expert_steps, train_expert_memory
from wmthesis.alphazero.latent_mdp import LatentMDP
from wmthesis.alphazero.selfplay import train_alphazero
from wmthesis.alphazero.variants import VARIANTS
from wmthesis.config import CollectConfig, for_profile, profile_name
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.envs.atari import boxing_env
from wmthesis.metrics import score_difference, score_summary
from wmthesis.references import published
from wmthesis.rollouts import collect
from wmthesis.stamp import git_commit
from wmthesis.runs import (built_on, first_run_seconds, hold, over_sittings, releasing_holds, results_folder, run_header,
                           work_folder, write_json)
from wmthesis.viz import record_frames, save_figure
from wmthesis.world_models.config import MemoryConfig, VisionConfig
from wmthesis.training import trained_seconds
from wmthesis.world_models.train import LatentStore, encode_store, train_memory, train_vision
from wmthesis.world_models.vision import VAEVision



@releasing_holds
def boxing_wm_alphazero(profile: str | None = None, seed: int = 0, variant: str | None = None,
                        progress: bool = True) -> dict:
    """Thesis 5.4.2: World Models + AlphaZero on Boxing, and why the thesis's version fails.

    Reuses the boxing-wm pipeline's random rollouts, vision and latents (the same artifacts
    under ``data/<profile>/boxing-wm/seed<seed>/``, cached), trains a deterministic memory in
    its own folder ``data/<profile>/boxing-wm-alphazero/seed<seed>/``, then self-play for the
    ``variant`` of :data:`~wmthesis.alphazero.variants.VARIANTS` (None: the default), resumable
    from its checkpoint. The variant, the
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

    Results under ``data/results/boxing-wm-alphazero/<profile>-seed<seed>/<variant>/``: figures,
    a rerun recording of an evaluation game, ``metrics.json``. Returns the metrics (``score``: the
    variant's);
    ``against_random``: each agent's mean minus random play's, with its standard error.
    """
    variants = (VARIANTS.check(variant).name,)
    profile = profile_name(profile)
    started = time.time()
    wm = work_folder(profile, NAMES.boxing_wm, seed)
    work = hold(work_folder(profile, NAMES.boxing_wm_alphazero, seed))
    out = results_folder(NAMES.boxing_wm_alphazero, profile, seed, variants[0])
    collect_cfg = for_profile(CollectConfig, profile)
    modelling = time.time()
    store = collect("boxing", collect_cfg.episodes, wm / "random.h5", workers=collect_cfg.workers, seed=seed,
                    preprocessing="world_models", max_steps=collect_cfg.max_steps, progress=progress)
    vae, _ = train_vision(store, wm, for_profile(VisionConfig, profile), seed=seed, progress=progress)
    latents = encode_store(store, vae, wm / "latents.h5", progress=progress)
    memory_cfg = for_profile(MemoryConfig, profile, kind="deterministic")
    memory, memory_history = train_memory(latents, work, memory_cfg, n_actions=18, seed=seed, progress=progress)
    vision = VAEVision(vae)
    modelling = time.time() - modelling  # this call's: a resumed or cached model trained in sittings before it
    trained = trained_seconds(wm / "vision.pt") + trained_seconds(work / f"memory-{memory_cfg.kind}.pt")
    stages = [(trained, modelling)]  # (seconds its checkpoints record over every sitting, this call's share)

    configs, runs, games, ablations, memories = {}, {}, {}, {}, {}
    for name in variants:
        configs[name] = cfg = for_profile(AlphaZeroConfig, profile, **VARIANTS.changes(name))
        expert = _expert(profile, seed, wm, vision, progress) if cfg.expert_games or cfg.memory_games else None
        searched = memory  # own-memory: a memory that also learned the expert's bouts
        if cfg.memory_games:
            searched, _ = train_expert_memory(lambda: boxing_env(cfg.noop_max), expert, vision, memory, latents, work,
                                              memory_cfg, cfg, seed, progress)
        memories[name] = searched
        playing = time.time()
        run = train_alphazero(lambda: boxing_env(cfg.noop_max), vision, searched, cfg, out_dir=work / name,
                                 seed=seed, progress=progress, rollouts=LatentStore(latents), expert=expert)
        stages.append((sum(g.get("seconds", 0.0) for g in run.curve), time.time() - playing))  # its games, every sitting
        runs[name] = {**run.summary(), "memory_steps": expert_steps(work, cfg, latents)}
        save_agent(work / agent_name(name), name, vae, searched, run, memory_cfg, git_commit())  # what `play` plays
        games[name] = evaluation_games(run, vision, searched, cfg, work / name, seed)
        if cfg.expert_games:
            ablations[f"AlphaZero {name}: policy head alone, no search"] = \
                policy_head_returns(run, vision, searched, cfg, work / name, seed)
            if run.pretrained is not None:  # (checkpoints written before it was kept have none)
                pretrained = evaluation_games(run, vision, searched, cfg, work / name, seed, pretrained=True)
                ablations[f"AlphaZero {name}: before self-play (search)"] = [g.score for g in pretrained]
    cfg = configs[variants[-1]]
    baselines = boxing_baselines(profile, wm, work, vision, cfg, seed)
    with EpisodeStore(store) as episodes:  # random play over the self-play games' length, for the curve
        random_in_store = [float(episodes.episode(i)["rewards"][:cfg.max_steps].sum()) for i in range(len(episodes))]

    mdp = LatentMDP(memories[variants[-1]])  # the diagnosis reads the last variant's games in its own memory
    all_games = [game for name in variants if memories[name] is memories[variants[-1]] for game in games[name]]
    depth = for_profile(DiagnosisConfig, profile).depth
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
    figures.append(save_figure(score_figure(scores), out / "scores.png"))
    shown = games[variants[-1]][0]
    recording = record_frames(out / "evaluation_game.rrd", {"observation": shown.frames},
                              {name: values[:RECORDING_STEPS] for name, values in
                               (("reward", shown.rewards), ("predicted_reward", shown.predicted_rewards),
                                ("root_value", shown.root_values))})
    metrics = {
        **run_header(NAMES.boxing_wm_alphazero, profile, seed, time.time() - started, variants=list(variants)),
        "score": scores[f"AlphaZero {variants[-1]}"], "scores": scores, "against_random": against_random,
        "evaluation": {"episodes": cfg.eval_episodes, "max_steps": cfg.eval_max_steps, "notes": baselines["notes"]},
        "random_play_in_store": {"max_steps": cfg.max_steps, **score_summary(random_in_store)},
        "reference": published(NAMES.boxing_wm_alphazero),
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
    metrics["first_run_wall_seconds"] = first_run_seconds(  # an earlier file of other self-play keeps no time
        out / "metrics.json", over_sittings(metrics["wall_seconds"], *stages), lambda earlier: _played(earlier.get("runs", {})) == _played(runs))
    write_json(out / "metrics.json", metrics, default=float)
    return metrics


def _played(runs: dict) -> dict:
    """What decides a set of self-play runs (their configs, games and each game's return), not
    how long they took: two runs the same here trained the same heads. A config written before a
    field existed reads that field's default."""
    defaults = dataclasses.asdict(AlphaZeroConfig())
    return json.loads(json.dumps({name: [{**defaults, **run["config"]}, run["games"], [g["return"] for g in run["curve"]]]
                                  for name, run in runs.items()}, default=float))


def _expert(profile: str, seed: int, wm: Path, vision, progress: bool):
    """``agent_seed -> ControllerMind``: notebook 02's controller (the CMA-ES mean) as the
    imitation variant's expert; trains it first (the boxing-wm pipeline, its steps cached) if it is missing."""
    make_mind, note = controller_minds(profile, wm, vision)
    if make_mind is None:
        built_on(NAMES.boxing_wm, profile, seed, progress=progress)
        make_mind, note = controller_minds(profile, wm, vision)
    if make_mind is None:
        raise RuntimeError(f"the imitation variant needs notebook 02's controller: {note}")
    return make_mind


