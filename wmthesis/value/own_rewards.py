"""PlaNet's reward head refit on the value agent's own bouts (beyond the thesis).

PlaNet's reward head learns Boxing's rewards from the bouts its model trained on: random play and a
few planner bouts, where the player is mostly hit. CEM asks it about the fights the value agent
plays, where the player lands punches. MuZero's lever, and the one that made MCTS pay in the World
Models memory (``wmthesis/alphazero/expert_memory.py``), is to train the model on the fights the
search plans for. Here only the reward head is refit: the model's transition, and with it the
value's features, stay frozen, so the learned value still holds.

The head is refit where CEM uses it: on the features of each taken action, ``(h_{t+1}, mean of
p(s_{t+1} | h_{t+1}))`` (:func:`~wmthesis.value.latent_value.episode_features`), against the reward that
followed, on every bout of a value run's store (its random bouts and its own), starting from the
model's head. ``ValuePlannerConfig.reward_head="own"`` plays CEM with it.
"""
from __future__ import annotations

from pathlib import Path

import torch
import torch.nn.functional as F

from wmthesis.data import EpisodeStore
from wmthesis.planet.config import PlaNetConfig
from wmthesis.value.config import LatentValueConfig, ValuePlannerConfig
from wmthesis.planet.rssm import RSSM
from wmthesis.planet.train import load_planet
from wmthesis.value.latent_value import LatentValue, episode_features, fit_value
from wmthesis.value.rounds import STORE, load_value
from wmthesis.runs import atomic_path
from wmthesis.utils import fingerprint

OWN_REWARDS = "own-rewards.pt"
REWARD_HEADS = (None, "own")  # ValuePlannerConfig.reward_head: PlaNet's own head, or the one refit here


@torch.inference_mode()
def reward_dataset(model: RSSM, store_path: str | Path, bits: int) -> tuple[torch.Tensor, torch.Tensor]:
    """Every stored episode's features after each taken action (N, H + S) and the reward that
    followed it (N,), the episodes filtered with the posterior as the value's are."""
    features, rewards = [], []
    with EpisodeStore(store_path, "r") as store:
        for index in range(len(store)):
            episode = store.episode(index)
            features.append(episode_features(model, episode, bits, index))
            rewards.append(torch.as_tensor(episode["rewards"], dtype=torch.float32, device=features[-1].device))
    return torch.cat(features), torch.cat(rewards)


def refit_reward_head(model: RSSM, features: torch.Tensor, rewards: torch.Tensor, config: LatentValueConfig,
                      seed: int) -> tuple[dict, dict]:
    """A copy of the model's reward head fitted as the value is fitted (:func:`~wmthesis.value.latent_value.fit_value`:
    ``config.fit_updates`` Adam steps of mean squared error, the value's ``batch_size`` and ``lr``)
    on ``features`` (N, H + S) and ``rewards`` (N,): the head has the shape of a one-head
    :class:`~wmthesis.value.latent_value.LatentValue`. Returns its state dict and the mean squared error
    on the data before and after."""
    head = LatentValue(features.shape[-1], model.reward_net[0].out_features).to(features.device)
    head.heads[0].load_state_dict(model.reward_net.state_dict())
    error = lambda: float(F.mse_loss(head(features), rewards))  # noqa: E731
    with torch.no_grad():
        before = error()
    fit_value(head, features, rewards, config, seed)
    with torch.no_grad():
        after = error()
    return head.heads[0].state_dict(), {"before": before, "after": after, "steps": len(rewards)}


def own_reward_head(model: RSSM, run_dir: str | Path, bits: int, config: LatentValueConfig, seed: int) -> dict:
    """The reward head refit on the bouts of the value run in ``run_dir``, saved there as
    :data:`OWN_REWARDS` and refit only when the run holds other bouts, or the model other weights
    (their fingerprint), than it was fitted on.
    Returns the saved record: ``state``, ``bouts``, ``fit`` (the error before and after)."""
    run_dir = Path(run_dir)
    with EpisodeStore(run_dir / STORE, "r") as store:
        bouts = len(store)
    path, weights = run_dir / OWN_REWARDS, fingerprint(model)
    if path.exists():
        saved = _read(path)
        if saved["bouts"] == bouts and saved.get("model") == weights:
            return saved
    features, rewards = reward_dataset(model, run_dir / STORE, bits)
    state, fit = refit_reward_head(model, features, rewards, config, seed)
    record = {"state": {k: v.cpu() for k, v in state.items()}, "bouts": bouts, "model": weights, "fit": fit}
    with atomic_path(path) as tmp:
        torch.save(record, tmp)
    return record


def with_own_rewards(model: RSSM, run_dir: str | Path) -> RSSM:
    """``model`` with the reward head refit in the value run ``run_dir`` (:func:`own_reward_head`,
    run first); a run without one is an error naming the file."""
    path = Path(run_dir) / OWN_REWARDS
    if not path.exists():
        raise FileNotFoundError(f"{path}: no reward head refit in this value run (own_reward_head makes it)")
    model.reward_net.load_state_dict(_read(path)["state"])
    return model


def _read(path: Path) -> dict:
    """A saved refit head; a file that is not one is an error naming it (delete it to refit)."""
    try:
        saved = torch.load(path, map_location="cpu", weights_only=True)
        return {"state": saved["state"], "bouts": saved["bouts"], "model": saved.get("model"), "fit": saved["fit"]}
    except Exception as error:  # torch raises several kinds on a truncated or foreign file
        raise ValueError(f"{path}: not a refit reward head ({type(error).__name__}: {error}); delete it to refit") from error


def check_reward_head(planner: ValuePlannerConfig) -> None:
    """A planner's ``reward_head`` must be one of :data:`REWARD_HEADS`, and ``own`` needs the
    imagined rewards from the reward head (``rewards="model"``): refused otherwise."""
    if planner.reward_head not in REWARD_HEADS:
        raise ValueError(f"reward_head must be one of {REWARD_HEADS}, got {planner.reward_head!r}")
    if planner.reward_head == "own" and planner.rewards != "model":
        raise ValueError(f"reward_head='own' plans with the reward head: rewards must be 'model', got {planner.rewards!r}")


def fit_for_planners(planet_run: str | Path, value_run: str | Path, planners, config: LatentValueConfig,
                     seed: int) -> None:
    """Refit the reward head in ``value_run`` (:func:`own_reward_head`) if any of ``planners``
    plans with it, before their bouts load it; each planner checked (:func:`check_reward_head`)."""
    for planner in planners:
        check_reward_head(planner)
    if any(planner.reward_head == "own" for planner in planners):
        model, planet, _ = load_planet(planet_run)
        own_reward_head(model, value_run, planet.bits, config, seed)


def planner_model(planet_run: str | Path, value_run: str | Path | None,
                  planner: ValuePlannerConfig | None) -> tuple[RSSM, PlaNetConfig, LatentValue | None]:
    """The frozen model of ``planet_run``, its config and the value of ``value_run`` (None without
    one, checked against the model as PlaNet trained it); the model with the reward head that
    ``planner`` plans with: PlaNet's (``reward_head=None``) or the one refit in ``value_run``
    (``"own"``)."""
    model, planet, _ = load_planet(planet_run)
    value = None if value_run is None else load_value(value_run, model)
    if planner is not None:
        check_reward_head(planner)
        if planner.reward_head == "own":
            with_own_rewards(model, value_run)
    return model, planet, value


__all__ = ["OWN_REWARDS", "REWARD_HEADS", "check_reward_head", "fit_for_planners", "planner_model", "reward_dataset", "refit_reward_head", "own_reward_head", "with_own_rewards"]
