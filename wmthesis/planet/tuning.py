"""Random search over PlaNet's KL scale x free nats (thesis 5.6.3-5.6.5), measured, not eyed.

The thesis tuned the two knobs jointly by random search and judged the runs "with a researcher
eye". Here each trial trains PlaNet (:func:`~wmthesis.planet.train.train_planet`) with one
setting and is measured by its final greedy test score, its open-loop prediction error at the
game's cut-off horizon (:data:`GAMES`), or both (:data:`OBJECTIVES`; ``SearchConfig.objective``).
The error is measured on held-out random episodes shared by every trial of a study
(``held-out.h5`` in its folder), on the moving pixels only
(:func:`~wmthesis.planet.prediction.moving_error`), so a blurry mean frame cannot win.
:func:`confirm_extremes` trains the best and the worst setting again with a second seed: the
search discriminates when the gap between them exceeds the seed-to-seed spread.

The study lives in an optuna storage: by default a SQLite file under ``data/search/``; any
optuna RDB URL (PostgreSQL: ``postgresql+psycopg2://user@host/db``) lets workers on many
machines share it: run the same command on each. Per machine, ``workers`` processes each run
trials until the study holds ``trials`` finished (complete or pruned) trials.

- Reproducible suggestions: :class:`TrialSeededSampler` draws trial *n*'s setting from
  (seed, n) alone, so the sequence does not depend on which worker runs which trial.
- Dead workers: workers beat a heartbeat into the storage; a RUNNING trial whose worker has
  not beaten for ``grace_period`` seconds is marked FAIL (by any live worker, or when the
  command runs again), and a new trial takes its place. Completed trials are never touched.
  (A worker killed between creating its trial and its first heartbeat leaves a RUNNING trial
  optuna cannot tell from a live one: mark it FAIL by hand.)
- A trial whose loss diverges (``FloatingPointError``) is PRUNED with the error in its
  ``diverged`` user attribute: it counts as a (bad) result, not as a crash.

Per trial, under ``data/search/FOLDER/trial-NNNN/``: the PlaNet run folder, ``metrics.json``
and ``open_loop.png``. ``FOLDER`` (:func:`study_dir`) is the study's name for the default storage,
and the name plus the storage's fingerprint (:func:`storage_fingerprint`) for any other: two
storages holding a study of the same name keep apart.

:func:`run_search` is the entry point; :func:`trial_rows`, :func:`ranked`, :func:`search_figure` read a study back.
"""
from __future__ import annotations

import functools
import hashlib
import math
import multiprocessing
import os
import socket
import time
import warnings
import zlib
from dataclasses import dataclass
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
import optuna
import sqlalchemy
import torch
from optuna.distributions import FloatDistribution
from optuna.samplers import RandomSampler
from optuna.trial import TrialState
from sqlalchemy.engine import make_url

from wmthesis.config import for_profile, profile_name
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.planet.config import SearchConfig
from wmthesis.planet.figures import open_loop_figure
from wmthesis.planet.profiles import planet_config
from wmthesis.planet.study import held_out_store, scene, score_run
from wmthesis.planet.train import train_planet
from wmthesis.runs import atomic_path, write_json
from wmthesis.utils import check_choice, data_dir, parallel_calls, secret_free


@dataclass(frozen=True)
class Game:
    """A search target: the environment, the thesis's best setting and the cut-off horizon
    (steps predicted open-loop) at which the prediction error is measured."""

    env: str
    thesis_kl_scale: float
    thesis_free_nats: float
    cutoff: int


# Cut-offs (not in the thesis): Boxing the planner's horizon, Freeway our longer one (a crossing
# takes longer than 12 steps). Boxing's setting is the thesis's (5.6.4), Freeway's our guess.
GAMES: dict[str, Game] = {
    NAMES.planet_boxing: Game("boxing", 3e-2, 12.0, 12),
    NAMES.planet_freeway: Game("freeway", 8e-3, 3.0, 25),
}
# name -> optuna directions (both: score, error)
OBJECTIVES: dict[str, tuple[str, ...]] = {"score": ("maximize",), "error": ("minimize",), "both": ("maximize", "minimize")}
FINISHED = (TrialState.COMPLETE, TrialState.PRUNED)  # what counts towards ``trials``
CONTEXT = 5                                          # open-loop context frames (as the thesis figures)
METRICS, FIGURE = "metrics.json", "open_loop.png"
# Study settings that must match when a study is continued (trials, workers, heartbeats may change).
_SETTINGS = ("seed", "objective", "kl_scale_low", "kl_scale_high", "free_nats_low", "free_nats_high",
             "env_steps", "max_episode_steps", "open_loop_sequences", "open_loop_length", "held_out_episodes")


# ---------------------------------------------------------------------------- sampler
class TrialSeededSampler(RandomSampler):
    """Optuna's random sampler whose draws for trial ``n`` depend only on ``(seed, n, name)``.

    A plain seeded :class:`~optuna.samplers.RandomSampler` in each of K workers would suggest
    the same settings K times; this one gives trial n the same setting whichever worker, on
    whichever machine, runs it. Float parameters only (log-uniform when ``log=True``)."""

    def __init__(self, seed: int = 0) -> None:
        super().__init__(seed)
        self.seed = seed

    def sample_independent(self, study, trial, param_name, param_distribution):
        if not isinstance(param_distribution, FloatDistribution) or param_distribution.step is not None:
            raise TypeError(f"{type(self).__name__} samples continuous floats only, not {param_name!r}")
        rng = np.random.default_rng([self.seed, trial.number, zlib.crc32(param_name.encode())])
        low, high = param_distribution.low, param_distribution.high
        if param_distribution.log:
            value = math.exp(rng.uniform(math.log(low), math.log(high)))
        else:
            value = rng.uniform(low, high)
        return float(min(max(value, low), high))


def suggest(trial: optuna.Trial, cfg: SearchConfig) -> dict[str, float]:
    """The trial's ``kl_scale`` (log-uniform) and ``free_nats`` (uniform)."""
    return {"kl_scale": trial.suggest_float("kl_scale", cfg.kl_scale_low, cfg.kl_scale_high, log=True),
            "free_nats": trial.suggest_float("free_nats", cfg.free_nats_low, cfg.free_nats_high)}


def planned_settings(cfg: SearchConfig, n: int) -> list[dict[str, float]]:
    """The settings trials 0..n-1 of a study with ``cfg`` get (no training, no storage)."""
    study = optuna.create_study(sampler=TrialSeededSampler(cfg.seed))
    return [suggest(study.ask(), cfg) for _ in range(n)]


# ---------------------------------------------------------------------------- storage
def default_storage() -> str:
    """The embedded default: a SQLite file ``data/search/studies.db``."""
    return f"sqlite:///{data_dir('search') / 'studies.db'}"


def storage_fingerprint(url: str) -> str:
    """8 hex digits naming a storage: the SHA-256 of its URL without the password (so a changed
    password keeps the name), a SQLite file's path made absolute (so the same file from
    another working directory keeps it)."""
    parsed = make_url(url)._replace(password=None)
    if parsed.get_backend_name() == "sqlite" and parsed.database not in (None, "", ":memory:"):
        parsed = parsed._replace(database=str(Path(parsed.database).absolute()))
    text = parsed.render_as_string(hide_password=False)
    return hashlib.sha256(text.encode()).hexdigest()[:8]


def study_dir(study_name: str, storage: str | None = None) -> Path:
    """The folder of a study's trials: ``data/search/STUDY`` for the default storage,
    ``data/search/STUDY-FINGERPRINT`` (:func:`storage_fingerprint`) for any other."""
    fingerprint = storage_fingerprint(storage or default_storage())
    if fingerprint == storage_fingerprint(default_storage()):
        return data_dir("search", study_name)
    return data_dir("search", f"{study_name}-{fingerprint}")


def make_storage(url: str, cfg: SearchConfig) -> optuna.storages.RDBStorage:
    """An optuna RDB storage with heartbeats (``cfg.heartbeat_interval``, ``cfg.grace_period``)."""
    engine = {"connect_args": {"timeout": 120}} if url.startswith("sqlite") else {"pool_pre_ping": True}  # sqlite: wait
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        try:
            return optuna.storages.RDBStorage(url, engine_kwargs=engine, heartbeat_interval=cfg.heartbeat_interval,
                                              grace_period=cfg.grace_period)
        except (sqlalchemy.exc.SQLAlchemyError, ImportError) as error:  # one line, not the driver's traceback
            raise OSError(secret_free(f"cannot open the optuna storage {url}: {str(error).splitlines()[0]}", url)) from None


def study_name(name: str, profile: str, objective: str) -> str:
    return f"{name}-{profile}-{objective}"


def open_study(name: str, cfg: SearchConfig, profile: str, storage: str | None = None) -> optuna.Study:
    """Create the study, or load it when it exists and was started with the same settings."""
    check_choice("search", name, GAMES)
    check_choice("objective", cfg.objective, OBJECTIVES)
    study = optuna.create_study(storage=make_storage(storage or default_storage(), cfg),
                                sampler=TrialSeededSampler(cfg.seed), load_if_exists=True,
                                study_name=study_name(name, profile, cfg.objective),
                                directions=list(OBJECTIVES[cfg.objective]))
    settings = {"env": GAMES[name].env, "profile": profile,
                **{key: getattr(cfg, key) for key in _SETTINGS}}
    stored = study.user_attrs.get("settings")
    if stored is None:
        study.set_user_attr("settings", settings)
    elif stored != settings:
        changed = {key: (stored.get(key), value) for key, value in settings.items() if stored.get(key) != value}
        raise ValueError(f"study {study.study_name!r} was started with other settings "
                         f"(stored, now): {changed}; use those or another --storage")
    return study


def load_study(name: str, profile: str | None = None, objective: str | None = None,
               storage: str | None = None) -> optuna.Study:
    """An existing study, for reading (notebook 06)."""
    profile = profile_name(profile)
    cfg = for_profile(SearchConfig, profile, **({"objective": objective} if objective else {}))
    return optuna.load_study(study_name=study_name(name, profile, cfg.objective),
                             storage=make_storage(storage or default_storage(), cfg),
                             sampler=TrialSeededSampler(cfg.seed))


# ---------------------------------------------------------------------------- one trial
def trial_dir(study: optuna.Study, number: int, storage: str | None = None) -> Path:
    """Trial ``number``'s folder, in the study's :func:`study_dir` for ``storage``."""
    folder = study_dir(study.study_name, storage) / f"trial-{number:04d}"
    folder.mkdir(parents=True, exist_ok=True)
    return folder


class SurplusTrial(Exception):
    """A trial created by a worker that raced another for the last place: it fails at once,
    before any work, and does not count towards ``trials``."""


def surplus_trial(trial: optuna.Trial, cfg: SearchConfig) -> bool:
    """Whether ``cfg.trials`` trials numbered below this one already finished or are running."""
    earlier = trial.study.get_trials(deepcopy=False, states=FINISHED + (TrialState.RUNNING,))
    return sum(other.number < trial.number for other in earlier) >= cfg.trials


def run_trial(trial: optuna.Trial, *, name: str, cfg: SearchConfig, profile: str, storage: str | None = None):
    """Train PlaNet with the trial's setting, measure it, save ``metrics.json`` and the
    open-loop figure in :func:`trial_dir`; return the objective value(s)."""
    game = GAMES[name]
    if surplus_trial(trial, cfg):
        trial.set_user_attr("surplus", True)
        raise SurplusTrial(f"trial {trial.number}: {cfg.trials} earlier trials already finished or running")
    params = suggest(trial, cfg)
    changes = dict(params, **{key: getattr(cfg, key) for key in ("env_steps", "max_episode_steps")
                              if getattr(cfg, key) is not None})
    config = planet_config(game.env, profile, **changes)
    folder = trial_dir(trial.study, trial.number, storage)
    metrics = {"study": trial.study.study_name, "trial": trial.number, "env": game.env, **params}
    try:
        measured = measure(name, config, folder / "run", cfg.seed, cfg, held_out_path(trial.study, name, cfg, storage))
    except FloatingPointError as error:
        write_json(folder / METRICS, dict(metrics, diverged=str(error)))
        trial.set_user_attr("diverged", str(error))
        raise optuna.TrialPruned(f"diverged: {error}") from error
    rollout = measured.pop("rollout")
    metrics.update(measured)
    fig = open_loop_figure(rollout, sequences=min(3, cfg.open_loop_sequences), columns=min(CONTEXT + game.cutoff, 20),
                           title=f"{name} trial {trial.number}: KL scale {params['kl_scale']:.3g}, "
                                 f"free nats {params['free_nats']:.2f}")
    with atomic_path(folder / FIGURE) as tmp:
        fig.savefig(tmp, dpi=70, format="png")
    plt.close(fig)
    write_json(folder / METRICS, metrics)
    for key in ("score", "error", "horizon"):
        trial.set_user_attr(key, metrics[key])
    trial.set_user_attr("folder", str(folder))
    trial.set_user_attr("worker", f"{socket.gethostname()}:{os.getpid()}")
    values = {"score": (metrics["score"],), "error": (metrics["error"],),
              "both": (metrics["score"], metrics["error"])}[cfg.objective]
    return values[0] if len(values) == 1 else values


def held_out_path(study: optuna.Study, name: str, cfg: SearchConfig, storage: str | None = None) -> Path:
    """The study's held-out episodes (``held-out.h5`` in its folder: ``held_out_episodes``
    random episodes seeded apart from any trial's), written on first use."""
    path = study_dir(study.study_name, storage) / "held-out.h5"
    if not path.exists():
        profile = study.user_attrs["settings"]["profile"]
        held_out_store(path, GAMES[name].env, planet_config(GAMES[name].env, profile), 20_000 + cfg.seed,
                       cfg.held_out_episodes)
    return path


def measure(name: str, config, run_dir: Path, seed: int, cfg: SearchConfig, held_out: Path) -> dict:
    """Train (or resume) one PlaNet run and measure it: ``score`` (its final greedy test, nan
    without one), ``error`` (held-out open-loop error on the moving pixels at the game's
    cut-off), ``horizon_errors``, the budget, and the ``rollout`` (for the figure)."""
    game = GAMES[name]
    result = train_planet(game.env, config, run_dir, seed=seed, progress=False)
    with EpisodeStore(held_out) as store:
        background, mean_frame = scene(store)
        scored = score_run(run_dir, store, background, mean_frame, context=CONTEXT,
                           horizon=cfg.open_loop_length - CONTEXT, sequences=cfg.open_loop_sequences, seed=cfg.seed)
    errors = scored["errors"]["model"]
    horizon = min(game.cutoff, len(errors))
    test = result["final_test"]
    return {"score": test["mean"] if test else math.nan, "score_std": test["std"] if test else math.nan,
            "error": float(errors[horizon - 1]), "horizon": horizon, "horizon_errors": errors,
            "repeat_last_error": scored["errors"]["repeat last"][horizon - 1],
            "mean_frame_error": scored["errors"]["mean frame"][horizon - 1], "diagnostics": scored["diagnostics"],
            "env_steps": result["env_steps"], "updates": result["updates"], "seconds": result["seconds"],
            "rollout": scored["rollout"]}


def _measure_again(name: str, row: dict, seed: int, cfg: SearchConfig, profile: str, held_out: Path) -> dict:
    changes = {key: getattr(cfg, key) for key in ("env_steps", "max_episode_steps") if getattr(cfg, key) is not None}
    config = planet_config(GAMES[name].env, profile, kl_scale=row["kl_scale"], free_nats=row["free_nats"], **changes)
    measured = measure(name, config, Path(row["folder"]) / f"seed{seed}", seed, cfg, held_out)
    measured.pop("rollout")
    return measured


def confirm_extremes(name: str, study: optuna.Study, *, storage: str | None = None, progress: bool = True) -> dict:
    """Train the best and the worst completed trial's setting again with a second seed (the
    study's seed + 1; in ``trial-NNNN/seed<S>/``, resumable) and measure them the same way.

    Returns ``best`` and ``worst`` (``number``, ``kl_scale``, ``free_nats``, ``values``: the
    measure with the study's seed and with the second), ``measure`` (``error``, or ``score``
    for a score study), ``gap`` (between the two settings' means), ``spread`` (the larger
    seed-to-seed difference of the two) and ``discriminates`` (gap > spread)."""
    settings = study.user_attrs["settings"]
    cfg = for_profile(SearchConfig, settings["profile"], **{k: settings[k] for k in _SETTINGS})
    measure_name = "score" if cfg.objective == "score" else "error"
    order = sorted([row for row in trial_rows(study) if row["state"] == "COMPLETE"],
                   key=lambda row: -row[measure_name] if measure_name == "score" else row[measure_name])
    if len(order) < 2:
        raise ValueError(f"study {study.study_name!r}: need two completed trials to compare, got {len(order)}")
    extremes = {"best": order[0], "worst": order[-1]}
    held_out = held_out_path(study, name, cfg, storage)
    again = parallel_calls([(_measure_again, name, row, cfg.seed + 1, cfg, settings["profile"], held_out)
                            for row in extremes.values()], progress)
    out = {"measure": measure_name, "seeds": [cfg.seed, cfg.seed + 1]}
    for (label, row), measured in zip(extremes.items(), again):
        out[label] = {"number": row["number"], "kl_scale": row["kl_scale"], "free_nats": row["free_nats"],
                      "values": [row[measure_name], measured[measure_name]]}
    means = {label: float(np.mean(out[label]["values"])) for label in extremes}
    out["gap"] = abs(means["best"] - means["worst"])
    out["spread"] = max(abs(np.subtract(*out[label]["values"])) for label in extremes)
    out["discriminates"] = bool(out["gap"] > out["spread"])
    write_json(study_dir(study.study_name, storage) / "confirmation.json", out)
    return out


# ---------------------------------------------------------------------------- workers
def work(name: str, cfg: SearchConfig, profile: str, storage: str, threads: int | None = None) -> None:
    """One worker: run trials until the study holds ``cfg.trials`` finished ones.

    Before each trial it counts finished plus running trials; when those already reach the
    target it does not start one but waits (a heartbeat) and fails stale trials, so a trial
    lost with a dead worker is replaced and the target is not overshot by live workers. Two
    workers may still both start a trial for the last place: the later-numbered one finds
    itself surplus and fails at once (:class:`SurplusTrial`)."""
    if threads:
        torch.set_num_threads(threads)
    study = open_study(name, cfg, profile, storage)
    objective = functools.partial(run_trial, name=name, cfg=cfg, profile=profile, storage=storage)
    while True:
        trials = study.get_trials(deepcopy=False, states=FINISHED + (TrialState.RUNNING,))
        if sum(trial.state in FINISHED for trial in trials) >= cfg.trials:
            return
        if len(trials) >= cfg.trials:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                optuna.storages.fail_stale_trials(study)
            time.sleep(cfg.heartbeat_interval)
            continue
        study.optimize(objective, n_trials=1, catch=(SurplusTrial,))


def run_search(name: str, *, trials: int | None = None, workers: int | None = None,
               storage: str | None = None, profile: str | None = None, objective: str | None = None,
               seed: int | None = None, **changes) -> optuna.Study:
    """Run (or continue) the search ``name`` (:data:`GAMES`) until ``trials`` trials finished.

    ``workers`` processes on this machine (1: in this process); ``storage`` an optuna RDB URL
    (default :func:`default_storage`); other arguments override the profile's
    :class:`~wmthesis.planet.config.SearchConfig`. Returns the study."""
    profile = profile_name(profile)
    given = dict(trials=trials, workers=workers, objective=objective, seed=seed, **changes)
    cfg = for_profile(SearchConfig, profile, **{k: v for k, v in given.items() if v is not None})
    storage = storage or default_storage()
    study = open_study(name, cfg, profile, storage)     # creates it once, before the workers race
    if len(study.get_trials(deepcopy=False, states=FINISHED)) >= cfg.trials:
        return study
    held_out_path(study, name, cfg, storage)             # likewise the held-out episodes
    if cfg.workers <= 1:
        work(name, cfg, profile, storage)
        return study
    context = multiprocessing.get_context("spawn")      # no forked torch/OpenMP or DB connections
    threads = max(1, (os.cpu_count() or 1) // cfg.workers)
    processes = [context.Process(target=work, args=(name, cfg, profile, storage, threads),
                                 name=f"search-worker-{k}") for k in range(cfg.workers)]
    for process in processes:
        process.start()
    for process in processes:
        process.join()
    failed = [p.exitcode for p in processes if p.exitcode != 0]
    if failed:
        raise RuntimeError(f"{len(failed)} of {len(processes)} search workers failed (exit codes {failed}); "
                           "finished trials are kept: run again to continue")
    return study


# ---------------------------------------------------------------------------- reading a study
def trial_rows(study: optuna.Study) -> list[dict]:
    """One dict per trial: number, state, kl_scale, free_nats, score, error, folder."""
    rows = []
    for trial in study.get_trials(deepcopy=False):
        rows.append({"number": trial.number, "state": trial.state.name, **trial.params,
                     **{key: trial.user_attrs.get(key) for key in ("score", "error", "horizon", "folder",
                                                                    "worker", "diverged", "surplus")}})
    return rows


def ranked(study: optuna.Study) -> list[dict]:
    """Completed trials, best first: by score (descending) or error (ascending); for ``both``
    by how many trials dominate each one (Pareto rank), then score."""
    rows = [row for row in trial_rows(study) if row["state"] == "COMPLETE"]
    objective = study.user_attrs["settings"]["objective"]

    def dominated(row):
        return sum(o["score"] >= row["score"] and o["error"] <= row["error"]
                   and (o["score"], o["error"]) != (row["score"], row["error"]) for o in rows)

    key = {"score": lambda r: -r["score"], "error": lambda r: r["error"],
           "both": lambda r: (dominated(r), -r["score"], r["error"])}[objective]
    return sorted(rows, key=key)


def search_figure(study: optuna.Study, game: str, measure: str = "score"):
    """KL scale against free nats coloured by ``measure`` (score or error), then ``measure``
    against each parameter; the thesis's best setting as a star."""
    rows = [row for row in trial_rows(study) if row["state"] == "COMPLETE"]
    thesis = GAMES[game]
    values = np.array([row[measure] for row in rows], dtype=float)
    kl = np.array([row["kl_scale"] for row in rows])
    nats = np.array([row["free_nats"] for row in rows])
    cmap = "viridis" if measure == "score" else "viridis_r"
    fig, axes = plt.subplots(1, 3, figsize=(11, 3.2))
    points = axes[0].scatter(kl, nats, c=values, cmap=cmap, s=30, edgecolor="k", linewidth=0.3)
    fig.colorbar(points, ax=axes[0], label=measure)
    axes[0].scatter([thesis.thesis_kl_scale], [thesis.thesis_free_nats], marker="*", s=160, c="tab:red",
                    label="thesis best")
    axes[0].set(xscale="log", xlabel="KL scale", ylabel="free nats")
    axes[0].legend(fontsize=7)
    for ax, x, label, best, log in ((axes[1], kl, "KL scale", thesis.thesis_kl_scale, True),
                                    (axes[2], nats, "free nats", thesis.thesis_free_nats, False)):
        ax.scatter(x, values, s=20)
        ax.axvline(best, color="tab:red", linestyle="--", linewidth=0.8, label="thesis best")
        ax.set(xlabel=label, ylabel=measure, xscale="log" if log else "linear")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    fig.suptitle(f"{study.study_name}: {len(rows)} completed trials", fontsize=9)
    fig.tight_layout()
    return fig


__all__ = ["GAMES", "OBJECTIVES", "Game", "TrialSeededSampler", "suggest", "planned_settings",
           "default_storage", "storage_fingerprint", "study_dir", "make_storage", "study_name", "open_study",
           "load_study", "run_trial", "work", "run_search", "trial_rows", "ranked", "search_figure", "trial_dir",
           "measure", "held_out_path", "confirm_extremes"]
