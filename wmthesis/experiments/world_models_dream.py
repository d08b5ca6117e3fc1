"""World Models that learn inside their dream, on Boxing, under Atari 100k's budget of real agent
steps (beyond the thesis: :mod:`wmthesis.world_models.dream`)."""
from __future__ import annotations

import dataclasses
import time

from wmthesis.config import for_profile, profile_name
from wmthesis.declarations import NAMES
from wmthesis.metrics import score_summary
from wmthesis.references import published
from wmthesis.runs import hold, read_json, releasing_holds, results_folder, run_header, work_folder, write_json
from wmthesis.stamp import git_commit
from wmthesis.viz import save_figure
from wmthesis.world_models.agent import save_agent
from wmthesis.world_models.config import BoxingEvaluationConfig, MemoryConfig, VisionConfig
from wmthesis.world_models.figures import dream_and_reality
from wmthesis.world_models.dream import controller_run, learn_in_dream
from wmthesis.world_models.evolution import score_bouts
from wmthesis.world_models.variants import DREAM_VARIANTS, dream_config
from wmthesis.world_models.vision import VAEVision


@releasing_holds
def boxing_wm_dream(profile: str | None = None, seed: int = 0, variant: str | None = None,
                    progress: bool = True) -> dict:
    """Learn the World Models controller inside the memory's dream under a budget of real agent
    steps, then score it on 10 full bouts (which do not count, as in Atari 100k). A finished run
    of the same config returns its metrics; one cut off starts again from nothing."""
    profile, name = profile_name(profile), DREAM_VARIANTS.check(variant).name
    cfg, out = dream_config(profile, seed, name), results_folder(NAMES.boxing_wm_dream, profile, seed, name)
    cached = read_json(out / "metrics.json")
    if cached is not None and cached.get("settings") == dataclasses.asdict(cfg):
        return cached
    work, started = hold(work_folder(profile, NAMES.boxing_wm_dream, seed, name)), time.time()
    memory_cfg = for_profile(MemoryConfig, profile)
    run = learn_in_dream(work, cfg, for_profile(VisionConfig, profile), memory_cfg, progress=progress)
    returns = score_bouts(run.params, VAEVision(run.vae), run.memory, for_profile(BoxingEvaluationConfig, profile).bouts,
                          cfg.noop_max)
    agent = save_agent(work / "agent.pt", run.vae, run.memory, controller_run(run, cfg), memory_cfg, git_commit())
    figure = save_figure(dream_and_reality(run.iterations, cfg.dream_length), out / "dream_and_reality.png")
    metrics = {**run_header(NAMES.boxing_wm_dream, profile, seed, time.time() - started, variant=name),
               "score": score_summary(returns), "returns": returns.tolist(),
               "budget": {"total": run.budget.total, "spent": run.budget.spent}, "iterations": run.iterations,
               "kept_iteration": run.kept, "reference": published(NAMES.boxing_wm_dream),
               "settings": dataclasses.asdict(cfg), "files": {"agent": str(agent), "figures": [str(figure)]}}
    write_json(out / "metrics.json", metrics, default=float)
    return metrics


__all__ = ["boxing_wm_dream"]
