"""The model study of thesis 5.6.1, 5.6.3 and 5.6.4, measured rather than eyed.

The thesis judged its Boxing models by their open-loop pictures (Fig. 59: a blurry blob with
PlaNet's defaults; Fig. 510: sharp boxers with KL scale 0.03 and free nats 12). Here each
configuration trains on the same random episodes for the same number of updates, with several
seeds, and is scored on held-out episodes: 5 context frames filtered, then 15 steps predicted
from the actions alone, the error counted on the moving pixels only
(:func:`~wmthesis.planet.prediction.moving_error`) beside the baselines "repeat the last context
frame" and "the mean frame", with the latent diagnostics that explain the result (KL against
the free nats, posterior and prior entropies).
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from wmthesis.config import for_profile
from wmthesis.data import EpisodeStore
from wmthesis.planet.config import PlanetEvaluationConfig
from wmthesis.rollouts import play_random_episode
from wmthesis.planet.prediction import background_frame, latent_diagnostics, moving_open_loop
from wmthesis.planet.train import load_planet
from wmthesis.planet.frames import make_planet_env

# The three configurations (:data:`~wmthesis.planet.variants.PLANET_BOXING`), in the thesis's order.
STUDY_VARIANTS = ("unchanged", "kl-scale", "free-nats")
BASELINES = ("repeat last", "mean frame")



def study_sizes(profile: str) -> dict:
    """The model study's sizes in ``profile`` (:meth:`~wmthesis.planet.config.PlanetEvaluationConfig.study`)."""
    return for_profile(PlanetEvaluationConfig, profile).study()


def held_out_store(path, env_name: str, config, seed: int, episodes: int) -> Path:
    """``episodes`` random episodes (seeded from (``seed``, i), apart from any run's) in an
    episode store at ``path``, with the config's frames; resumes a partly written store."""
    env = make_planet_env(env_name, config)
    try:
        with EpisodeStore(path, "a", env=env_name, preprocessing="planet", seed=seed,
                          obs_shape=(config.frame_size, config.frame_size, 3),
                          env_options=dict(bits=config.bits, crop=config.crop)) as store:
            for index in range(len(store), episodes):
                store.append_episode(**play_random_episode(env, seed, index))
    finally:
        env.close()
    return Path(path)


def scene(store: EpisodeStore, every: int = 10) -> tuple[np.ndarray, np.ndarray]:
    """The ``background`` (per-pixel median) and the ``mean frame`` (uint8) of every
    ``every``-th frame of a store: what the moving-pixel error and its baseline need."""
    frames = np.concatenate([store.episode(i)["observations"][::every] for i in range(len(store))])
    return background_frame(frames), frames.mean(0).round().astype(np.uint8)


def score_run(run_dir, held_out: EpisodeStore, background: np.ndarray, mean_frame: np.ndarray, *,
              context: int = 5, horizon: int = 15, sequences: int = 32, seed: int = 0) -> dict:
    """A trained run scored on ``sequences`` chunks of held-out episodes (the same chunks for
    every run with the same ``seed``): moving-pixel errors by horizon 1..``horizon`` of the
    ``model`` and the :data:`BASELINES`, those of the context frames' reconstructions
    (``filtered``, :func:`~wmthesis.planet.prediction.moving_open_loop`),
    :func:`~wmthesis.planet.prediction.latent_diagnostics`,
    and the open-loop ``rollout`` (for the pictures)."""
    model, config, meta = load_planet(run_dir)
    batch = held_out.sample_chunks(sequences, context + horizon, np.random.default_rng(seed))
    result = moving_open_loop(model, batch["observations"], batch["actions"], background=background,
                              mean_frame=mean_frame, context=context, bits=config.bits, seed=seed)
    errors = {name: [float(v) for v in result[name]] for name in ("model", *BASELINES)}
    filtered = {name: [float(v) for v in e] for name, e in result["filtered"].items()}
    return {"errors": errors, "filtered": filtered,
            "diagnostics": latent_diagnostics(model, batch["observations"], batch["actions"], bits=config.bits, seed=seed),
            "updates": meta["updates"], "free_nats": config.free_nats, "kl_scale": config.kl_scale,
            "rollout": result["rollout"]}


def summarise(scores: dict[str, list[dict]], horizons=(1, 5, 10, 15)) -> dict:
    """Per configuration (``{variant: [score_run per seed]}``): the model's mean and seed
    spread (min, max) of the error at each of ``horizons``, and the baselines' errors.
    Also ``beats_baselines`` (every seed below both baselines at horizons 1-5) and the
    diagnostics' seed means."""
    out = {}
    for variant, runs in scores.items():
        model = np.array([run["errors"]["model"] for run in runs])             # (seeds, H)
        baselines = {name: np.array([run["errors"][name] for run in runs]).mean(0) for name in BASELINES}
        out[variant] = {
            "model": {h: {"mean": float(model[:, h - 1].mean()), "min": float(model[:, h - 1].min()),
                          "max": float(model[:, h - 1].max())} for h in horizons},
            **{name: {h: float(curve[h - 1]) for h in horizons} for name, curve in baselines.items()},
            "beats_baselines": bool(all((model[:, :5] < curve[:5]).all() for curve in baselines.values())),
            "diagnostics": {key: float(np.mean([run["diagnostics"][key] for run in runs]))
                            for key in runs[0]["diagnostics"]},
        }
    return out


def study_table(metrics: dict) -> str:
    """The study's summary as a markdown table: per configuration, the model's error on the
    moving pixels at each horizon (seed mean, [min, max]) beside the baselines, and the
    latent diagnostics."""
    summary = metrics["summary"]
    first = next(iter(summary.values()))
    horizons = list(first["model"])
    rows = ["| configuration | " + " | ".join(f"+{h}" for h in horizons)
            + " | beats both baselines at +1..+5 | KL (nats) | free nats | posterior / prior entropy |",
            "|---" * (len(horizons) + 5) + "|"]
    for variant, entry in summary.items():
        run = metrics["runs"][f"{variant}-seed{metrics['seeds'][0]}"]
        cells = [f"{v['mean']:.4f} [{v['min']:.4f}, {v['max']:.4f}]" for v in entry["model"].values()]
        diag = entry["diagnostics"]
        rows.append(f"| {variant}: KL scale {run['kl_scale']:g}, free nats {run['free_nats']:g} | " + " | ".join(cells)
                    + f" | {'yes' if entry['beats_baselines'] else 'no'} | {diag['kl']:.2f} | {run['free_nats']:g} | "
                    f"{diag['posterior_entropy']:.1f} / {diag['prior_entropy']:.1f} |")
    for name in ("repeat last", "mean frame"):
        rows.append(f"| baseline: {name} | " + " | ".join(f"{first[name][h]:.4f}" for h in horizons) + " | | | | |")
    return "\n".join(rows)


def study_contrast(metrics: dict) -> str:
    """Which configuration of the study predicts best at its first and at its last horizon, with
    its error on the moving pixels (the seeds' mean): the thesis's contrast of Fig. 59 and 510, measured."""
    summary = metrics["summary"]
    horizons = list(next(iter(summary.values()))["model"])

    def best(h):
        variant = min(summary, key=lambda v: summary[v]["model"][h]["mean"])
        return f"{variant}'s ({summary[variant]['model'][h]['mean']:.4f})"

    return (f"lowest error at +{horizons[0]}: {best(horizons[0])}; at +{horizons[-1]}: {best(horizons[-1])} "
            f"(of {', '.join(summary)})")


__all__ = ["study_contrast", "study_table", "study_sizes", "STUDY_VARIANTS", "BASELINES", "held_out_store", "scene", "score_run", "summarise"]
