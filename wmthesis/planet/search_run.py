"""The KL scale x free nats search as an experiment (thesis 5.6.3-5.6.5, notebook 06):
``python -m wmthesis reproduce planet-boxing-search`` runs the study to its end
(:func:`~wmthesis.planet.tuning.run_search`, resuming), trains its best and worst settings again
with a second seed (:func:`~wmthesis.planet.tuning.confirm_extremes`) and writes one
``metrics.json`` with what the summary tables: the best trial's open-loop error on the held-out
bouts, x 1000 (:data:`SCALE`: a readable number at the table's one decimal; lower is better)."""
from __future__ import annotations

import math
import time

import optuna

from wmthesis.declarations import NAMES
from wmthesis.planet.tuning import confirm_extremes, ranked, run_search, trial_dir
from wmthesis.runs import results_folder, run_header, write_json
from wmthesis.variants import no_variant

EXPERIMENT, GAME = NAMES.planet_boxing_search, NAMES.planet_boxing
SCALE = 1000.0  # the summary's number: the best trial's error x SCALE


def search_metrics(study: optuna.Study, check: dict, profile: str, seed: int, seconds: float) -> dict:
    """The metrics of a finished ``study`` and its confirmation ``check``: ``score`` (the best
    trial's error x :data:`SCALE`, as ``mean``), ``best`` and ``worst`` (trial, KL scale, free
    nats, error), ``trials`` (completed), ``confirmation`` and ``first_run_wall_seconds`` (the
    completed trials' summed durations: the search's time from scratch, its confirmation apart)."""
    done = [t for t in study.trials if t.state == optuna.trial.TrialState.COMPLETE]
    order = ranked(study)
    best, worst = ({k: row[k] for k in ("number", "kl_scale", "free_nats", "error", "score")
                    if row[k] is not None and math.isfinite(row[k])} for row in (order[0], order[-1]))
    headline = (f"best trial {best['number']} (KL scale {best['kl_scale']:.3g}, free nats {best['free_nats']:.2f}): "
                f"error {best['error']:.4f}, worst trial {worst['number']} {worst['error']:.4f} over {len(done)} trials; "
                f"again with seed {check['seeds'][1]}: gap {check['gap']:.4f}, spread {check['spread']:.4f} "
                f"({'discriminates' if check['discriminates'] else 'does not discriminate'})")
    return {**run_header(EXPERIMENT, profile, seed, seconds, study=study.study_name), "headline": headline,
            "first_run_wall_seconds": round(sum(t.duration.total_seconds() for t in done), 1),
            "score": {"mean": SCALE * best["error"], "episodes": 1}, "trials": len(done), "best": best, "worst": worst,
            "confirmation": check, "files": {"figures": [str(trial_dir(study, row["number"]) / "open_loop.png")
                                                         for row in (order[0], order[-1])]}}


def write_search_metrics(study: optuna.Study, check: dict, profile: str, seed: int, seconds: float) -> dict:
    """:func:`search_metrics`, written to ``data/results/planet-boxing-search/PROFILE-seedS/``."""
    metrics = search_metrics(study, check, profile, seed, seconds)
    write_json(results_folder(EXPERIMENT, profile, seed) / "metrics.json", metrics)
    return metrics


def planet_boxing_search(profile: str, seed: int = 0, variant: str | None = None, progress: bool = True) -> dict:
    """The search of ``profile`` (its study's seed ``seed``) run to its end, confirmed, its metrics
    written and returned."""
    no_variant(EXPERIMENT, variant)
    started = time.time()
    study = run_search(GAME, profile=profile, seed=seed)
    check = confirm_extremes(GAME, study, progress=progress)
    return write_search_metrics(study, check, profile, seed, time.time() - started)


__all__ = ["EXPERIMENT", "GAME", "SCALE", "search_metrics", "write_search_metrics", "planet_boxing_search"]
