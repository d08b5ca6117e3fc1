"""Fit the observation decoders of the shipped agents to their frozen encoders and models, and write
them beside the agents (``decoder.pt``), so that a fresh clone draws reconstructions, dreams and
open-loop predictions without training. The agents' files, and every number built on them, stay
as they are.

    python tools/fit_decoders.py world-models          # boxing-wm seed 0's vision (shared by the AlphaZero agents)
    python tools/fit_decoders.py planet [--seeds 0,1,2] [--games boxing,freeway] [--bouts 8 --planner-bouts 4]

Each fit resumes from its checkpoint in the agent's work folder; a decoder file already written
for the same encoder or model is kept.
"""
from __future__ import annotations

import argparse
import time

from wmthesis.config import CollectConfig, for_profile
from wmthesis.rollouts import collect
from wmthesis.runs import work_folder
from wmthesis.stamp import git_commit


def world_models(profile: str = "quick", seed: int = 0) -> None:
    """boxing-wm's vision of ``seed``: its decoder fitted on the run's own random rollouts (the
    same seeded store the vision was trained on), with the vision's own updates and batch."""
    from wmthesis.world_models.agent import load_agent
    from wmthesis.world_models.config import VisionConfig
    from wmthesis.world_models.decoder import DECODER_NAME, fit_decoder, reconstruction_error, save_decoder
    from wmthesis.data import EpisodeStore

    work = work_folder(profile, "boxing-wm", seed)
    agent = load_agent(work / "agent-separable-64.pt")
    cfg = for_profile(CollectConfig, profile)
    store = collect("boxing", cfg.episodes, work / "random.h5", workers=cfg.workers, seed=seed,
                    preprocessing="world_models", max_steps=cfg.max_steps)
    vision = for_profile(VisionConfig, profile)
    started = time.time()
    vae, history = fit_decoder(agent.vision.vae, store, work, vision, seed=seed)
    with EpisodeStore(store) as episodes:
        frames = episodes.episode(len(episodes) - 1)["observations"][::25]
    fitted_on = {
        "what": "the decoder, fitted after the agent to its frozen encoder (encoder and agent unchanged)",
        "data": f"boxing-wm's random rollouts of seed {seed} ({cfg.episodes} episodes, world_models frames): "
                "the store the vision was trained on",
        "loss": "negative Bernoulli log-likelihood of a frame given one reparameterised sample of its latent",
        "updates": history[-1]["step"], "batch_size": vision.batch_size,
        "val_reconstruction": history[-1]["val_reconstruction"],
        "best_val_reconstruction": min(h["val_reconstruction"] for h in history),
        "pixel_error_validation_episode": reconstruction_error(vae, frames),
        "seconds": round(time.time() - started, 1), "commit": git_commit(),
    }
    save_decoder(work / DECODER_NAME, vae, fitted_on)
    print(fitted_on)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("which", choices=["world-models", "planet"])
    parser.add_argument("--seeds", default="0,1,2")
    parser.add_argument("--games", default="boxing,freeway")
    parser.add_argument("--bouts", type=int, default=8, help="real bouts to fit a PlaNet decoder on")
    parser.add_argument("--planner-bouts", type=int, default=4, help="of them, played by the agent's planner")
    args = parser.parse_args()
    if args.which == "world-models":
        world_models()
    else:
        from wmthesis.planet.decoder import fit_shipped

        for game in args.games.split(","):
            for seed in map(int, args.seeds.split(",")):
                fit_shipped(game, seed, bouts=args.bouts, planner_bouts=args.planner_bouts)


if __name__ == "__main__":
    main()
