"""A trained World Models agent as :func:`wmthesis.load` gives it (thesis 4.2): the vision (with its
decoder where one ships beside the agent), the memory, the controller, on Boxing as it was scored.

    agent = wmthesis.load("boxing-wm")
    z = agent.vision(frames)                  # (N, 64, 64, 3) uint8 -> (N, 16)
    agent.vision.decode(z)                    # -> (N, 64, 64, 3) uint8
    agent.dream(frames, actions, context=60, horizon=10)   # the memory's open-loop dream
    agent.play(bouts=1)                       # [44.0]: the first scored bout
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from wmthesis.agents import TrainedAgent, check_episode
from wmthesis.declarations import NAMES
from wmthesis.world_models.agent import load_agent
from wmthesis.world_models.controller import Controller, ControllerMind
from wmthesis.world_models.decoder import DECODER_NAME, MissingDecoder, attach_decoder


def shipped_decoder(vision, folder: Path) -> dict | None:
    """Attach the decoder file in ``folder`` (or, for an agent seeing through boxing-wm's vision,
    in boxing-wm's folder of the same seed) to ``vision``; its ``fitted_on``, or None where none
    ships (the vision then refuses to decode, saying why)."""
    candidates = [folder / DECODER_NAME, folder.parent.parent / NAMES.boxing_wm / folder.name / DECODER_NAME]
    for path in candidates:
        if path.is_file():
            return attach_decoder(vision.vae, path)
    vision.vae.decoder = MissingDecoder(
        f"no decoder ships for this vision (looked for {', '.join(map(str, candidates))}): an agent file keeps only "
        "the encoder; `python tools/fit_decoders.py world-models` fits one to it")
    return None


class WorldModelsAgent(TrainedAgent):
    """boxing-wm's agent: ``vision`` (:class:`~wmthesis.world_models.vision.VAEVision`),
    ``memory`` (the MDN-RNN), ``controller`` (:class:`~wmthesis.world_models.controller.Controller`)."""

    decoded = "the vision's reconstructions and the dream's frames"
    fit_decoder = "python tools/fit_decoders.py world-models"

    def __init__(self, path: Path, experiment: str, variant: str | None, profile: str, seed: int):
        loaded = load_agent(path)
        super().__init__(path, experiment, variant, profile, seed, loaded.info)
        task = loaded.info["task"]
        self.vision, self.memory, self.game = loaded.vision, loaded.memory, task["env"]
        self.params = loaded.params  # the controller's flat parameters as CMA-ES evolved them (play plays `controller`)
        self.controller = Controller.from_flat(loaded.params, task["latent_size"], task["hidden_size"],
                                               task["n_actions"]).eval()
        self.decoder_info = shipped_decoder(self.vision, Path(path).parent)
        self.max_steps = loaded.info["controller_config"]["max_steps"]

    def env(self):
        """Boxing with World Models frames (64, 64, 3) uint8 and the scored bouts' no-op starts,
        played where the agent sees them (:class:`~wmthesis.envs.atari.ScoredStart`)."""
        from wmthesis.envs.atari import ScoredStart, make_atari

        return ScoredStart(make_atari("Boxing", preprocessing="world_models"),
                           self.info["controller_config"]["noop_max"])

    def mind(self) -> ControllerMind:
        return ControllerMind(self.vision, self.memory, self.controller)

    def scored_seeds(self, bouts: int) -> list[int]:
        from wmthesis.world_models.evolution import final_bout_seeds

        return [int(s) for s in final_bout_seeds(bouts)]

    def play_bouts(self, bouts: int, frames: list | None = None, on_bout=None) -> list[dict]:
        """The scored bouts all at once, as the controller was scored (the batched game)."""
        from wmthesis.envs.vector import make_game
        from wmthesis.world_models.evolution import evaluate_population, final_bout_seeds

        cfg = self.info["controller_config"]
        game, shown = make_game("boxing", bouts, noop_max=cfg["noop_max"]), [] if frames is not None else None
        try:
            returns, steps = evaluate_population(self.controller.get_flat()[None], game, self.vision, self.memory,
                                                 seeds=final_bout_seeds(bouts), max_steps=cfg["max_steps"],
                                                 frames=shown)
        finally:
            game.close()
        plays = [{"bout": k, "return": float(r), "steps": int(n)} for k, (r, n) in enumerate(zip(returns[0], steps[0]))]
        if frames is not None:
            frames += [np.stack([f[k] for f in shown[:p["steps"] + 1]]) for k, p in enumerate(plays)]
        for p in plays if on_bout is not None else ():
            on_bout(p)
        return plays

    def snapshot(self, mind: ControllerMind) -> tuple:
        """The mind's ``z``, ``h`` and memory state once it planned."""
        return mind.z.clone(), mind.h.clone(), tuple(part.clone() for part in mind.state)

    def thoughts(self, snapshots: list) -> list:
        """What the controller weighed (its action scores) and what the memory dreams from each
        snapshot: ``horizon`` steps of its mixture's most likely path with the controller acting
        in the dream, with the rewards the memory predicts, decoded at the steps ahead in
        ``shown``; the vision's reconstruction of the frame (frames without a decoder: left out).
        The snapshots dream together, one batch."""
        from wmthesis.thoughts import Thought

        z = torch.cat([zs for zs, _, _ in snapshots])
        h = torch.cat([hs for _, hs, _ in snapshots])
        state = tuple(torch.cat([s[k] for _, _, s in snapshots], 1) for k in range(2))
        latents, rewards, scores = dream_path(self.controller, self.memory, z, h, state, self.horizon)
        ahead = [j for j in self.shown if j <= self.horizon]
        thoughts = [Thought(imagined_rewards=rewards[b], scores={"controller": scores[b]}) for b in range(len(z))]
        if self.decoder_info is not None:
            frames = self.vision.decode(torch.cat([z[:, None], latents[:, [j - 1 for j in ahead]]], 1).flatten(0, 1))
            frames = frames.reshape(len(z), 1 + len(ahead), *frames.shape[1:])
            for thought, shown in zip(thoughts, frames):
                thought.seen, thought.imagined = shown[0], dict(zip(ahead, shown[1:]))
        return thoughts

    @torch.inference_mode()
    def step_prediction(self, mind: ControllerMind, frame, action: int) -> dict:
        """The memory's step from the frame: its mixture's most likely next latent, decoded, and its reward."""
        from wmthesis.world_models.prediction import most_likely

        z = self.vision(torch.as_tensor(np.asarray(frame))[None])
        out = self.memory.step(z, torch.tensor([action], device=z.device), mind.state)
        shown = self.vision.decode(most_likely(out.next_latent))[0] if self.decoder_info is not None else None
        return {"frame": None if shown is None else np.asarray(shown), "reward": float(out.reward.reshape(-1)[0])}

    def thought(self, mind: ControllerMind):
        """The :meth:`thoughts` of ``mind`` now."""
        return self.thoughts([self.snapshot(mind)])[0]

    def dream(self, frames, actions, context: int = 60, horizon: int = 10) -> dict:
        """The memory warmed on ``context`` real steps of an episode (``frames`` (T, 64, 64, 3)
        uint8, ``actions`` (T,), ``actions[t]`` taken at ``frames[t]``), then dreaming ``horizon`` steps along the actions taken from its
        mixture's most likely path: ``truth`` and ``prediction`` frames (horizon, 64, 64, 3),
        ``pixel_error`` and ``latent_error`` per step."""
        from wmthesis.world_models.prediction import open_loop

        frames = np.asarray(frames)
        actions = check_episode(frames, actions, context + horizon, self.memory.n_actions)
        return open_loop(self.vision.vae, self.memory, frames, actions, context, horizon)


@torch.inference_mode()
def dream_path(controller: Controller, memory, z: torch.Tensor, h: torch.Tensor, state: tuple,
               horizon: int) -> tuple[torch.Tensor, np.ndarray, np.ndarray]:
    """The memory's dream from ``z`` (B, L), ``h`` (B, H) and its LSTM ``state`` (each (1, B, H))
    with the controller acting in it: latents (B, horizon, L) along the mixture's most likely
    path, the rewards it predicts (B, horizon), and the controller's scores now (B, A)."""
    from wmthesis.world_models.prediction import most_likely

    scores = controller(z, h).cpu().numpy()
    latents, rewards = [], []
    for _ in range(horizon):
        out = memory.step(z, controller(z, h).argmax(-1), state)
        z, h, state = most_likely(out.next_latent), out.hidden, out.state
        latents.append(z)
        rewards.append(out.reward.reshape(-1).cpu().numpy())
    return torch.stack(latents, 1), np.stack(rewards, 1), scores


def load_trained(path: Path, *, experiment: str, variant: str | None, profile: str, seed: int) -> WorldModelsAgent:
    return WorldModelsAgent(path, experiment, variant, profile, seed)


__all__ = ["WorldModelsAgent", "load_trained", "shipped_decoder", "dream_path"]
