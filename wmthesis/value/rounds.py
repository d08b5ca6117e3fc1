"""The value fitted in rounds (:mod:`~wmthesis.value.latent_value`): on random bouts first, then each
round adds epsilon-greedy bouts of the value agent to its store and refits on all of it (a fitted-Q
iteration on its own play), resumable from its checkpoint; the agent is the round chosen on
validation bouts (or the mean of the last rounds' values), and the rounds' values read back."""
from __future__ import annotations

import copy
import dataclasses
import time
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from wmthesis.data import EpisodeStore
from wmthesis.rollouts import play_random_episode
from wmthesis.value.config import LatentValueConfig
from wmthesis.planet.rssm import RSSM
from wmthesis.planet.shipped import AGENT_NAME
from wmthesis.value.latent_value import (LatentValue, TARGETS, best_values, episode_features, fit_value, log_scaled,
                                   reward_sums, round_ensemble, td_targets)
from wmthesis.value.shipped import load_value_agent
from wmthesis.value.play import bout_pool, evaluation_seeds, greedy_returns, play_values, validation_seeds
from wmthesis.runs import atomic_path
from wmthesis.training import with_added_defaults
from wmthesis.utils import check_choice, derive_seeds, fingerprint


STORE, CHECKPOINT = "episodes.h5", "value.pt"


def value_dataset(model: RSSM, path: Path, config: LatentValueConfig, bits: int, cache: list[dict]) -> list[dict]:
    """Per episode of the store at ``path``: ``features`` (T, H + S), the (discounted, for
    ``td``) reward sums ``sums`` (T,), and each step's ``beliefs`` (T, H) and ``states`` (T, S)
    for the bootstrap. ``cache`` holds the episodes already read (the model is frozen), so each
    round computes only its new bouts."""
    discount = config.discount if config.target != "reward-sum" else 1.0
    with EpisodeStore(path, "r") as store:
        for index in range(len(cache), len(store)):
            episode = store.episode(index)
            features, beliefs, states = episode_features(model, episode, bits, index, beliefs=True)
            sums = reward_sums(episode["rewards"], config.reward_steps, discount)
            if log_scaled(config):  # floored at a reward just past the window
                sums = np.log(sums + discount ** config.reward_steps)
            sums = torch.as_tensor(sums, device=features.device)
            cache.append({"features": features, "sums": sums, "beliefs": beliefs, "states": states})
    return cache


def _fit_round(value: LatentValue, model: RSSM, episodes: list[dict], config: LatentValueConfig, seed: int,
               fitted: bool) -> float:
    """Fit ``value`` on the episodes: to the reward sums, or (``td``) ``td_iterations`` times to
    targets bootstrapped from the value as it stands (nothing to bootstrap from before its first
    fit, ``fitted`` False). Returns the last fit's loss."""
    features = torch.cat([e["features"] for e in episodes])
    if config.target != "td":  # the (discounted) sums themselves
        return fit_value(value, features, torch.cat([e["sums"] for e in episodes]), config, seed)
    share = dataclasses.replace(config, fit_updates=max(1, config.fit_updates // config.td_iterations))
    loss = 0.0
    for iteration in range(config.td_iterations):
        targets = [td_targets(e["sums"], best_values(model, value, e["beliefs"], e["states"]) if fitted or iteration
                              else torch.zeros_like(e["sums"]), config.reward_steps, config.discount) for e in episodes]
        loss = fit_value(value, features, torch.cat(targets), share, int(derive_seeds(seed, iteration)[0]))
    return loss


def train_value(model: RSSM, bits: int, env, config: LatentValueConfig, run_dir, *, seed: int,
                progress: bool = True, first_steps: int = 500, make_env: tuple | None = None) -> dict:
    """Play ``random_bouts`` random bouts into ``run_dir/episodes.h5``, fit the value on them;
    then ``config.rounds`` times: ``bouts_per_round`` epsilon-greedy bouts of the value agent
    into the same store, refit on all of it. After each fit the value plays ``validation_bouts``
    greedy bouts (:func:`validation_seeds`) and ``test_bouts`` (:func:`evaluation_seeds`); the
    value of the round with the best validation mean is kept as the agent (fitted Q swings from
    round to round as its own bouts change the data), chosen without looking at the test bouts.
    Resumable: every bout is stored as it ends, the values and the scores after each round.
    Returns ``curve`` (one entry per round: ``round``, ``episodes`` (of its own), ``validation``,
    ``returns`` (the test bouts), ``first_returns`` (their first ``first_steps`` steps), ``mean``,
    ``std``, ``loss``), ``best_round``, the ``agent`` (the scores of the values that make it, with
    their ``rounds``: the best round, or with ``config.agent_rounds`` the mean of the last rounds)
    ``run_dir`` and ``seconds`` (the rounds' wall time over every sitting; None for a checkpoint
    written before it kept them). Every round's value is kept (``rounds`` in the checkpoint). Without
    ``config.score_rounds`` the rounds play no greedy bouts (their entries hold ``round``,
    ``episodes`` and ``loss``; ``best_round`` is None) and only the agent is scored. With
    ``make_env`` (``(fn, *args)``, module-level, building ``env``'s game) the bouts play two at a
    time (:func:`bout_pool`)."""
    check_choice("value target", config.target, TARGETS)
    if config.agent_rounds < 0:
        raise ValueError(f"agent_rounds must be >= 0, got {config.agent_rounds}")
    if not config.score_rounds and not config.agent_rounds:
        raise ValueError("score_rounds=False needs agent_rounds > 0: without the rounds' validation bouts "
                         "there is no round to choose")
    run_dir = Path(run_dir)
    device = next(model.parameters()).device
    value = _first_value(model, config, seed)
    saved = run_dir / CHECKPOINT
    state = torch.load(saved, map_location=device, weights_only=False) if saved.exists() else {"curve": []}
    if "value" in state:
        _check_resumable(state["config"], config, saved)
        _check_model(state, model, saved)
        value.load_state_dict(state["value"])
    curve, cache = state["curve"], []
    with bout_pool(model, make_env) as pool:
        for round_ in tqdm(range(len(curve), config.rounds + 1), desc="value rounds", disable=not progress):
            start = time.perf_counter()
            episodes = _store_bouts(run_dir / STORE, env, model, value, bits, config, seed, round_, pool)
            data = value_dataset(model, run_dir / STORE, config, bits, cache)
            loss = _fit_round(value, model, data, config, int(derive_seeds(seed, 5, round_)[0]), fitted=round_ > 0)
            scores = _scores(env, model, value, bits, config, seed, first_steps, pool) if config.score_rounds else {}
            curve.append({"round": round_, "episodes": episodes, **scores, "loss": loss})
            rounds = state.setdefault("rounds", {})
            rounds[round_] = {key: v.clone() for key, v in value.state_dict().items()}
            if config.score_rounds and best_round(curve) == round_:
                state["best"] = rounds[round_]
            state["seconds"] = state.get("seconds", 0.0) + time.perf_counter() - start
            with atomic_path(saved) as tmp:
                torch.save({"value": value.state_dict(), **({"best": state["best"]} if "best" in state else {}),
                            "rounds": rounds, "curve": curve, "config": dataclasses.asdict(config),
                            "model": fingerprint(model), "seconds": state["seconds"]}, tmp)
        agent = _agent(env, model, bits, config, run_dir, seed=seed, progress=progress, first_steps=first_steps,
                       pool=pool)
    return {"curve": curve, "best_round": best_round(curve) if config.score_rounds else None, "agent": agent,
            "run_dir": str(run_dir), "seconds": state.get("seconds")}


def _store_bouts(path: Path, env, model: RSSM, value: LatentValue, bits: int, config: LatentValueConfig, seed: int,
                 round_: int, pool: tuple | None) -> int:
    """The store at ``path`` filled up to ``round_``: the random bouts, then ``bouts_per_round``
    epsilon-greedy bouts of ``value`` per round, each stored in order as it ends. Returns the
    number of the value agent's own bouts."""
    with EpisodeStore(path, "a", preprocessing="planet", seed=seed, obs_shape=env.observation_space.shape) as store:
        for index in range(len(store), config.random_bouts):
            store.append_episode(**play_random_episode(env, seed, index))
        seeds = [derive_seeds(seed, 4, index, n=2)
                 for index in range(len(store), config.random_bouts + round_ * config.bouts_per_round)]
        play_values(env, model, value, bits, seeds, config.epsilon, pool,
                    on_done=lambda index, episode: store.append_episode(**episode))
        return len(store) - config.random_bouts


def _scores(env, model: RSSM, value: LatentValue, bits: int, config: LatentValueConfig, seed: int,
            first_steps: int, pool: tuple | None = None, validation: bool = True) -> dict:
    """A value's greedy bouts: ``validation`` (:func:`validation_seeds`) and ``validation_mean``
    (unless not ``validation``); the test bouts' ``returns`` (:func:`evaluation_seeds`),
    ``first_returns`` (their first ``first_steps`` steps), ``mean`` and ``std``: the value as it
    ships (:func:`as_shipped`; the fitted value itself goes on unrounded)."""
    value, chosen = as_shipped(copy.deepcopy(value)), {}
    if validation:
        returns = greedy_returns(env, model, value, bits, [validation_seeds(seed, k) for k in range(config.validation_bouts)],
                                  pool=pool)
        chosen = {"validation": returns, "validation_mean": float(np.mean(returns))}
    returns, first = greedy_returns(env, model, value, bits, [evaluation_seeds(seed, k) for k in range(config.test_bouts)],
                                     first_steps, pool)
    return {**chosen, "returns": returns, "first_returns": first, "mean": float(np.mean(returns)),
            "std": float(np.std(returns))}


def agent_rounds(curve: list[dict], config: LatentValueConfig) -> list[int]:
    """The rounds whose values make the agent: the one with the best validation mean
    (:func:`best_round`), or the last ``config.agent_rounds`` (their mean, :func:`round_ensemble`)."""
    if config.agent_rounds < 0:
        raise ValueError(f"agent_rounds must be >= 0, got {config.agent_rounds}")
    return [entry["round"] for entry in curve[-config.agent_rounds:]] if config.agent_rounds else [best_round(curve)]


def _agent(env, model: RSSM, bits: int, config: LatentValueConfig, run_dir: Path, *, seed: int, progress: bool,
           first_steps: int, pool: tuple | None = None) -> dict:
    """The agent's scores with its ``rounds`` (:func:`agent_rounds`): the chosen round's entry of
    the curve, or the mean of several rounds' values playing the same bouts, once. Which rounds
    make the agent is kept in the checkpoint (``agent``), where :func:`load_value` reads it."""
    path = run_dir / CHECKPOINT
    state = torch.load(path, map_location=next(model.parameters()).device, weights_only=False)
    chosen = agent_rounds(state["curve"], config)
    kept = state.get("agent", {})
    if kept.get("rounds") == chosen and "returns" in kept:
        return kept
    if not config.agent_rounds:
        agent = {**state["curve"][chosen[0]], "rounds": chosen}
    else:
        rounds = round_values(model, bits, run_dir, seed=seed, progress=progress)
        value = round_ensemble([rounds[r] for r in chosen], config.hidden_size, log_scaled(config))
        agent = {"rounds": chosen, **_scores(env, model, value, bits, config, seed, first_steps, pool,
                                             validation=config.score_rounds)}
        state = torch.load(path, map_location=next(model.parameters()).device, weights_only=False)  # with the rounds
    with atomic_path(path) as tmp:
        torch.save({**state, "agent": agent}, tmp)
    return agent


def _first_value(model: RSSM, config: LatentValueConfig, seed: int) -> LatentValue:
    """The value before its first fit: its weights from the seed alone, however the process began."""
    with torch.random.fork_rng(devices=[]):
        torch.manual_seed(int(derive_seeds(seed, 7)[0]))
        value = LatentValue(model.belief_size + model.state_size, config.hidden_size, config.heads, log_scaled(config))
    return value.to(next(model.parameters()).device)


def round_values(model: RSSM, bits: int, run_dir, *, seed: int, progress: bool = True) -> dict[int, dict]:
    """Every round's value (round -> state dict) of a :func:`train_value` run. A run saved before
    the rounds were kept has them refitted from its store, once, and kept: the same episodes,
    seeds and first weights give the same fits, each checked against the loss its round saved
    (a refit that differs raises rather than pass off another value as the run's)."""
    path = Path(run_dir) / CHECKPOINT
    state = _load_checked(path, model)
    rounds, curve = state.get("rounds", {}), state["curve"]
    if all(entry["round"] in rounds for entry in curve):
        return rounds
    config = LatentValueConfig(**with_added_defaults(LatentValueConfig, state["config"]))
    value, data = _first_value(model, config, seed), value_dataset(model, path.parent / STORE, config, bits, [])
    last = max(entry["round"] for entry in curve if entry["round"] not in rounds)
    for entry in tqdm(curve[:last + 1], desc="refitting the rounds", disable=not progress):
        round_ = entry["round"]
        if round_ not in rounds:
            episodes = data[:config.random_bouts + entry["episodes"]]
            loss = _fit_round(value, model, episodes, config, int(derive_seeds(seed, 5, round_)[0]), fitted=round_ > 0)
            if not np.isclose(loss, entry["loss"], rtol=1e-4, atol=0.0):
                raise ValueError(f"{path}: refitting round {round_} gave loss {loss:.6g}, the run saved "
                                 f"{entry['loss']:.6g}: not the run's computation (another seed or code?)")
            rounds[round_] = {key: v.clone() for key, v in value.state_dict().items()}
        value.load_state_dict(rounds[round_])
    with atomic_path(path) as tmp:
        torch.save({**state, "rounds": rounds}, tmp)
    return rounds


def best_round(curve: list[dict]) -> int:
    """The round whose value scored best on the validation bouts (the earliest of ties)."""
    return max(curve, key=lambda entry: (entry["validation_mean"], -entry["round"]))["round"]


def _check_resumable(saved: dict, config: LatentValueConfig, path: Path) -> None:
    """A run goes on only with the config it was started with; ``rounds`` may grow, and
    ``agent_rounds`` (which fitted values make the agent) may change."""
    saved = with_added_defaults(LatentValueConfig, saved)  # fields added since: what the run did
    changed = sorted(k for k, v in dataclasses.asdict(config).items()
                     if k not in ("rounds", "agent_rounds") and saved.get(k) != v)
    if changed:
        raise ValueError(f"{path} was fitted with another LatentValueConfig ("
                         + ", ".join(f"{k}: {saved.get(k)} -> {getattr(config, k)}" for k in changed)
                         + "); use a new run folder, or the same config (only rounds may change)")


def _check_model(state: dict, model: RSSM, path: Path) -> None:
    """A value belongs to the frozen model it was fitted on (its weights' fingerprint; a value
    saved before fingerprints were kept passes)."""
    saved, given = state.get("model"), fingerprint(model)
    if saved is not None and saved != given:
        raise ValueError(f"{path} was fitted on another model (weights {saved}, this model's {given}); "
                         "use the PlaNet run it was fitted on, or fit a value for this model in a new folder")


def _load_checked(path: Path, model: RSSM) -> dict:
    """A saved value run's checkpoint, on ``model``'s device, refused for another model."""
    if not path.exists():
        raise FileNotFoundError(f"{path}: no fitted value (run train_value first)")
    state = torch.load(path, map_location=next(model.parameters()).device, weights_only=False)
    _check_model(state, model, path)
    return state


def _kept_mean(state: dict, rounds: list[int], path: Path) -> LatentValue:
    """The mean of kept rounds' values (:func:`round_ensemble`) of a saved run."""
    missing = [r for r in rounds if r not in state.get("rounds", {})]
    if missing:
        raise ValueError(f"{path} does not keep the values of rounds {missing}; run round_values on it first")
    return round_ensemble([state["rounds"][r] for r in rounds], state["config"]["hidden_size"], log_scaled(state["config"]))


def as_shipped(value: LatentValue) -> LatentValue:
    """``value`` with its weights rounded to half precision, as an agent's file keeps them
    (:mod:`~wmthesis.planet.agent_file`): every bout a value agent plays is the shipped agent's."""
    with torch.no_grad():
        for weights in value.parameters():
            weights.copy_(weights.half().float())
    return value


def load_rounds(run_dir, model: RSSM, rounds: list[int]) -> LatentValue:
    """The mean of the values of ``rounds`` of a :func:`train_value` run for ``model``
    (:func:`round_ensemble`; the rounds kept, :func:`round_values`), as it ships (:func:`as_shipped`)."""
    path = Path(run_dir) / CHECKPOINT
    return as_shipped(_kept_mean(_load_checked(path, model), rounds, path))


def load_value(run_dir, model: RSSM) -> LatentValue:
    """The agent of a :func:`train_value` run for ``model``: its chosen round's value
    (:func:`best_round`), or the mean of the rounds' values that made its agent (``agent_rounds``),
    as it ships (:func:`as_shipped`). Where the run's checkpoint is not here but its agent file is
    (a fresh clone), the value that file ships (:func:`~wmthesis.value.shipped.load_value_agent`:
    refused unless it was fitted on the PlaNet agent file beside it)."""

    path, shipped = Path(run_dir) / CHECKPOINT, Path(run_dir) / AGENT_NAME
    if not path.exists() and shipped.is_file():
        value = load_value_agent(shipped).value
        if value.heads[0][0].in_features != model.belief_size + model.state_size:
            raise ValueError(f"{shipped} holds no value for this model")
        return value.to(next(model.parameters()).device)
    state = _load_checked(path, model)
    chosen = state.get("agent", {}).get("rounds", [])
    if chosen and ("best" not in state or chosen != [best_round(state["curve"])]):
        return as_shipped(_kept_mean(state, chosen, path))
    if "best" not in state:
        raise ValueError(f"{path} was fitted before values were chosen on validation bouts; "
                         "run train_value again in a new folder")
    config = LatentValueConfig(**with_added_defaults(LatentValueConfig, state["config"]))
    value = LatentValue(model.belief_size + model.state_size, config.hidden_size, config.heads,
                        log_scaled(config)).to(next(model.parameters()).device)
    value.load_state_dict(state["best"])
    return as_shipped(value).eval()


__all__ = ["STORE", "CHECKPOINT", "train_value", "agent_rounds", "round_values", "best_round", "load_rounds", "load_value", "as_shipped"]
