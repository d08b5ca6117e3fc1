"""PlaNet's observation decoder (thesis 4.4.1), kept in a file of its own beside a shipped agent.

A shipped PlaNet agent keeps its RSSM without the observation model (planning never decodes).
Drawing its reconstructions and open-loop predictions (Fig. 58, 59, 511) needs one:
:func:`fit_decoder` fits a decoder to a frozen model on the posterior states it filters from
real bouts (the model, and every score built on it, unchanged), minimising the thesis's
observation term (a Gaussian of unit variance on the frame, summed over pixels);
:func:`save_decoder` writes it in half precision with the fingerprint of the model it decodes
and what it was fitted on; :func:`attach_decoder` puts it into a loaded model after checking
the fingerprint.

    episodes = real_episodes(model, config, env, seeds)       # frames and actions, real bouts
    decoder, history = fit_decoder(model, config, episodes, run_dir)
"""
from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np
import torch

from wmthesis.core import RandomMind, loop
from wmthesis.declarations import NAMES
from wmthesis.envs.preprocessing import to_float
from wmthesis.planet.agent import PlanetMind
from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.networks import vision_networks
from wmthesis.planet.rssm import RSSM, gaussian_nll, one_hot_previous
from wmthesis.rollouts import EpisodeBuffer
from wmthesis.runs import read_agent_file, save_agent_file
from wmthesis.training import train
from wmthesis.utils import fingerprint

FORMAT = "wmthesis-planet-decoder"
FORMAT_VERSION = 1
DECODER_NAME = "decoder.pt"


def model_fingerprint(model: RSSM) -> str:
    """A hash of the model's weights but its decoder's: what a decoder file is for."""
    parts = torch.nn.ModuleDict({name: module for name, module in model.named_children() if name != "decoder"})
    return fingerprint(parts)


def real_episodes(model: RSSM, config: PlaNetConfig, env, seeds: list[int], planner_bouts: int) -> list[dict]:
    """One bout of ``env`` per seed: the first ``planner_bouts`` played by the model's greedy
    CEM planner, the rest by random actions. Each: ``observations`` (T, S, S, 3) uint8 and
    ``actions`` (T,) int64."""
    episodes = []
    for k, seed in enumerate(seeds):
        planner = k < planner_bouts
        mind = PlanetMind.from_config(model, config, seed) if planner else RandomMind(model.n_actions, seed)
        record = EpisodeBuffer()
        loop(env, mind, policy="deterministic", callbacks=[mind, record] if planner else [record], seed=int(seed),
             train_mode=False)
        episodes.append({key: record.episode[key] for key in ("observations", "actions")})
    return episodes


@torch.no_grad()
def posterior_features(model: RSSM, episode: dict, bits: int, generator: torch.Generator) -> torch.Tensor:
    """``[h_t, s_t]`` (T, H + S) filtered along one episode, ``s_t`` drawn from the posterior."""
    device = next(model.parameters()).device
    frames = to_float(torch.as_tensor(episode["observations"], device=device)[None], bits, noise=generator)
    actions = one_hot_previous(torch.as_tensor(episode["actions"], device=device)[None], model.n_actions)
    trajectory = model.observe(model.encode(frames), actions, generator)
    return torch.cat([trajectory.beliefs, trajectory.states], -1)[0]


def fit_decoder(model: RSSM, config: PlaNetConfig, episodes: list[dict], run_dir: str | Path, *, seed: int = 0,
                steps: int = 3000, batch_size: int = 128, draws: int = 2, progress: bool = True):
    """A decoder of the config's sizes fitted to the frozen ``model`` on ``episodes`` (the last one
    held out for validation): each frame's ``draws`` posterior features -> the frame, minimising
    the Gaussian observation term. Resumable from ``run_dir/decoder-fit.pt``; returns the best
    decoder on the held-out episode and the history."""
    torch.manual_seed(seed)
    generator = torch.Generator(next(model.parameters()).device).manual_seed(seed)
    features, frames = [], []
    for episode in episodes:
        for _ in range(draws):
            features.append(posterior_features(model, episode, config.bits, generator))
            frames.append(torch.as_tensor(episode["observations"]))
    rows = np.cumsum([0] + [len(f) for f in features])
    held_out = np.arange(rows[-1 - draws], rows[-1])
    splits = {"train": np.arange(rows[-1 - draws]), "val": held_out}
    features, frames = torch.cat(features), torch.cat(frames)
    _, decoder, _ = vision_networks(config.frame_size, config.depth, config.belief_size + config.state_size)
    decoder = decoder.to(features.device)
    optimiser = torch.optim.Adam(decoder.parameters(), lr=config.lr, eps=config.adam_eps)

    def sample(split, rng):
        index = torch.as_tensor(rng.choice(splits[split], batch_size))
        return features[index], to_float(frames[index], config.bits).to(features.device)

    def loss_fn(batch):
        x, target = batch
        mean = decoder(x).movedim(-3, -1)
        observation = gaussian_nll(target, mean, config.decoder_variance, dims=3).mean()
        return {"loss": observation, "observation_mse": (target - mean).pow(2).mean().detach()}

    history = train(decoder, optimiser, loss_fn, sample, steps=steps, checkpoint=Path(run_dir) / "decoder-fit.pt",
                    config={"model": model_fingerprint(model), "steps": steps, "batch_size": batch_size,
                            "draws": draws, "rows": int(rows[-1])},
                    seed=seed, eval_every=100, patience=5, desc="decoder", progress=progress)
    return decoder.eval(), history


def save_decoder(path: str | os.PathLike, model: RSSM, decoder: torch.nn.Module, fitted_on: dict) -> Path:
    """``decoder`` in half precision at ``path``, with the fingerprint of ``model`` and ``fitted_on``."""
    state = {k: v.detach().cpu().half() for k, v in decoder.state_dict().items()}
    return save_agent_file(path, FORMAT, FORMAT_VERSION, model=model_fingerprint(model), decoder=state,
                           fitted_on=fitted_on)


def attach_decoder(model: RSSM, config: PlaNetConfig, path: str | os.PathLike) -> dict:
    """Load the decoder file at ``path`` into ``model`` (float32); returns its ``fitted_on``. A
    missing or foreign file, or one fitted to another model, raises an error naming it."""
    path = Path(path)
    saved = read_agent_file(path, "PlaNet decoder", FORMAT, FORMAT_VERSION)
    if saved["model"] != model_fingerprint(model):
        raise ValueError(f"{path} decodes the model {saved['model']}, not this one ({model_fingerprint(model)})")
    _, decoder, _ = vision_networks(config.frame_size, config.depth, config.belief_size + config.state_size)
    decoder.load_state_dict({k: v.float() for k, v in saved["decoder"].items()})
    model.decoder = decoder.to(next(model.parameters()).device).eval()
    return saved["fitted_on"]


def fit_shipped(game: str, seed: int, profile: str = "quick", bouts: int = 8, planner_bouts: int = 4) -> Path:
    """The decoder of the shipped PlaNet agent of ``game`` (boxing: planet-boxing-agent;
    freeway: planet-freeway's tuned agent) and ``seed``, fitted on ``bouts`` real bouts (the
    first ``planner_bouts`` by its planner, the others random; reset seeds 10,000 on, apart
    from every scored bout), written beside the agent file."""
    from wmthesis.planet.shipped import AGENT_NAME, load_agent
    from wmthesis.planet.frames import make_planet_env
    from wmthesis.runs import work_folder
    from wmthesis.stamp import git_commit

    folder = work_folder(profile, NAMES.planet_boxing_agent, seed) if game == "boxing" else \
        work_folder(profile, NAMES.planet_freeway, seed, "freeway-tuned")
    agent = load_agent(folder / AGENT_NAME)
    started = time.time()
    seeds = [10_000 + k for k in range(bouts)]
    scored = {int(b[0]) for b in agent.info["bouts"]}
    if scored & set(seeds):
        raise ValueError(f"the fitting bouts {sorted(scored & set(seeds))} are scored bouts")
    env = make_planet_env(game, agent.planet)
    try:
        episodes = real_episodes(agent.model, agent.planet, env, seeds, planner_bouts)
    finally:
        env.close()
    decoder, history = fit_decoder(agent.model, agent.planet, episodes, folder, seed=seed)
    best = min(history, key=lambda h: h["val_loss"])
    fitted_on = {
        "what": "the observation decoder, fitted after the agent to its frozen model (model and agent unchanged)",
        "data": f"{bouts} real {game} bouts (reset seeds {seeds[0]}-{seeds[-1]}, apart from the scored bouts): "
                f"{planner_bouts} by the agent's greedy CEM planner, {bouts - planner_bouts} random; "
                "features: posterior samples filtered along them (2 draws a frame); the last bout held out",
        "loss": "Gaussian observation term of unit variance, summed over pixels (the thesis's)",
        "steps": history[-1]["step"], "frames": int(sum(len(e["actions"]) for e in episodes)),
        "val_observation_mse": best["val_observation_mse"],
        "seconds": round(time.time() - started, 1), "commit": git_commit(),
    }
    path = save_decoder(folder / DECODER_NAME, agent.model, decoder, fitted_on)
    print(path, fitted_on)
    return path


__all__ = ["FORMAT", "FORMAT_VERSION", "DECODER_NAME", "model_fingerprint", "real_episodes", "posterior_features",
           "fit_decoder", "save_decoder", "attach_decoder", "fit_shipped"]
