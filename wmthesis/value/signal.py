"""How far a learned value reads a PlaNet model's imagination (beyond the thesis).

CEM with the value (:mod:`~wmthesis.value.planner`) scores a candidate by Q at the states
it imagines: the first step's from the real belief, every later step's from states sampled from
the model's prior. Search pays only where Q at those imagined states still tells good from bad.
This module measures it along recorded episodes: from each step's posterior ``(h_t, s_t)``,
``depth`` steps are imagined along the actions that were taken, and Q after the next taken action
is set against the rewards that really followed,

    corr( Q(f_d(t)),  r_{t+d} + ... + r_{t+d+n-1} )

where ``f_d(t)`` are the value's features after ``a_{t+d}`` from the state imagined ``d`` steps
past ``t``. Depth 0 is the value where it was fitted (the posterior); the fall with depth is what
the imagined steps of a search lose.
"""
from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from wmthesis import runs as run_store
from wmthesis.config import for_profile
from wmthesis.data import EpisodeStore
from wmthesis.declarations import NAMES
from wmthesis.value.config import LatentValueConfig
from wmthesis.value.own_rewards import planner_model
from wmthesis.planet.rssm import RSSM
from wmthesis.value.latent_value import after_action, episode_features, reward_sums
from wmthesis.value.planner import imagined_state
from wmthesis.value.rounds import STORE
from wmthesis.value.variants import value_folder

SIGNAL_DEPTHS = (0, 1, 2, 3, 6)  # imagined steps: 0 the real belief; CEM's quick horizons reach 1, 2 and 5
SIGNAL_BOUTS = 20  # the last bouts of the value run's store that the signal is measured on


def imagined_features(model: RSSM, beliefs: torch.Tensor, states: torch.Tensor, actions: torch.Tensor, depth: int,
                      generator: torch.Generator | None = None) -> torch.Tensor:
    """From every step's posterior, beliefs (T, H) and states (T, S) before actions (T,) long,
    ``depth`` steps imagined along the actions taken, then the value's features after the next
    one: (T - depth, H + S), row t those after ``a_{t+depth}``. The imagined states are the
    prior's samples (CEM's, drawn with ``generator``) or, with ``generator`` None, its mean.
    Depth 0: the features after each action from the posterior itself."""
    if isinstance(depth, bool) or not isinstance(depth, int) or depth < 0:
        raise ValueError(f"depth must be an integer >= 0, got {depth!r}")
    count = max(0, len(actions) - depth)  # an episode shorter than the depth has no such step
    belief, state = beliefs[:count], states[:count]
    if depth:
        along = torch.stack([F.one_hot(actions[k:k + count], model.n_actions).float() for k in range(depth)], 1)
        pick = lambda prior: imagined_state(prior, generator, "mean" if generator is None else "sample")  # noqa: E731
        for step in model.imagined_steps(belief, state, along, pick):
            belief, state = step.belief, step.state
    return after_action(model, belief, state, actions[depth:])


@torch.inference_mode()
def value_signal(model: RSSM, value: nn.Module, episodes: list[dict], bits: int, *, reward_steps: int = 3,
                 depths: tuple[int, ...] = (0, 1, 2, 3), seed: int = 0) -> dict[int, float]:
    """Per depth, the correlation over every step of ``episodes`` (dicts with ``observations``
    (T, size, size, 3) uint8, ``actions`` (T,), ``rewards`` (T,)) between Q at the features
    imagined that deep (:func:`imagined_features`, the prior's samples as CEM draws them, seeded
    by ``seed``) and the sum of the ``reward_steps`` real rewards that followed (module docstring)."""
    generator = torch.Generator(next(model.parameters()).device).manual_seed(int(seed))
    q, sums = {d: [] for d in depths}, {d: [] for d in depths}
    for index, episode in enumerate(episodes):
        _, beliefs, states = episode_features(model, episode, bits, int(seed) + index, beliefs=True)
        actions = torch.as_tensor(episode["actions"], device=beliefs.device)
        real = reward_sums(episode["rewards"], reward_steps)
        for depth in depths:
            q[depth].append(value(imagined_features(model, beliefs, states, actions, depth, generator)).cpu().numpy())
            sums[depth].append(real[depth:])
    return {d: float(np.corrcoef(np.concatenate(q[d]), np.concatenate(sums[d]))[0, 1]) for d in depths}


SIGNAL_VERSION = 1  # raise it when the measurement changes: kept signals are then measured again


def signal_models(profile: str, seed: int) -> dict:
    """The SHA-256 of the shipped files a seed's signal measures: the PlaNet agent and its value
    (None where a file is missing)."""
    from wmthesis.agents import agent_file

    return {name: run_store.file_sha256(path) if (path := agent_file(name, None, profile, seed)).is_file() else None
            for name in (NAMES.planet_boxing_agent, NAMES.planet_boxing_value)}


def seed_value_signal(profile: str, seed: int, depths: tuple[int, ...] = SIGNAL_DEPTHS,
                      bouts: int = SIGNAL_BOUTS) -> dict[int, float]:
    """:func:`value_signal` of ``seed``'s default Boxing value on its frozen PlaNet model, on the
    last ``bouts`` bouts of the value run's store (all of it where it holds fewer); kept in the seed's ``planning-budget`` results
    (``value_signal.json``) and read from there when it holds these depths and bouts, was measured
    on the agent files that ship now (their SHA-256) and by this :data:`SIGNAL_VERSION` of the
    measurement, so a fresh clone reads the committed measurement and a changed model measures again."""
    path = run_store.results_folder(NAMES.planning_budget, profile, seed) / "value_signal.json"
    kept, models = run_store.read_json(path), signal_models(profile, seed)
    if kept and kept.get("depths") == list(depths) and kept.get("bouts") == bouts and "correlation" in kept \
            and kept.get("models") == models and kept.get("version") == SIGNAL_VERSION:
        return {int(depth): value for depth, value in kept["correlation"].items()}
    value_run = value_folder(profile, seed)
    if not (value_run / STORE).is_file():
        raise FileNotFoundError(f"{value_run / STORE}: no fitted value for seed {seed} in {profile}; run "
                                f"`python -m wmthesis reproduce planet-boxing-value --profile {profile} --seed {seed}`")
    model, planet, value = planner_model(run_store.work_folder(profile, NAMES.planet_boxing_agent, seed), value_run, None)
    with EpisodeStore(value_run / STORE, "r") as store:
        episodes = [store.episode(index) for index in range(max(0, len(store) - bouts), len(store))]
    signal = value_signal(model, value, episodes, planet.bits, depths=tuple(depths), seed=seed,
                          reward_steps=for_profile(LatentValueConfig, profile).reward_steps)
    run_store.write_json(path, {"version": SIGNAL_VERSION, "models": models, "depths": list(depths), "bouts": bouts,
                                "episodes": len(episodes),
                                "steps": int(sum(len(e["actions"]) for e in episodes)),
                                "correlation": {str(depth): value for depth, value in signal.items()}})
    return signal


def plot_value_signal(signals: dict[int, dict[int, float]]):
    """The value's correlation with the rewards that followed against the imagined steps, each seed
    a line (``signals``: seed -> depth -> correlation), the mean in black. Returns the figure."""
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(4.5, 3.2))
    depths = sorted(set.intersection(*(set(signal) for signal in signals.values())))
    for seed, signal in sorted(signals.items()):
        ax.plot(depths, [signal[d] for d in depths], "o-", lw=1, ms=3, alpha=0.6, label=f"seed {seed}")
    ax.plot(depths, [np.mean([signal[d] for signal in signals.values()]) for d in depths], "k-", lw=2, label="mean")
    ax.axhline(0, color="grey", lw=0.5)
    ax.set_xlabel("imagined steps before the action (0: the real belief)")
    ax.set_ylabel("corr(Q, rewards that followed)")
    ax.set_title("how far the value reads the model's imagination", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    return fig


__all__ = ["imagined_features", "value_signal", "seed_value_signal", "signal_models", "plot_value_signal", "SIGNAL_DEPTHS",
           "SIGNAL_BOUTS", "SIGNAL_VERSION"]
