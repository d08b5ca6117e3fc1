"""A trained PlaNet agent as :func:`wmthesis.load` gives it (thesis 4.4): the RSSM (with its
observation decoder where one ships beside the agent) and its planner, discrete CEM, on the game
as it was scored (:mod:`wmthesis.value.trained` adds a learned value at the end of CEM's horizon).

    agent = wmthesis.load("planet-boxing-agent")
    agent.open_loop(frames, actions, context=5)     # reconstructions, then 10 imagined frames
    mind = agent.mind(); mind.plan(frame)           # one CEM plan from the belief
    agent.play(bouts=1)                             # its first scored bout
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from wmthesis.agents import TrainedAgent, check_episode
from wmthesis.planet.agent import PlanetMind
from wmthesis.planet.shipped import NoDecoder, load_agent, play_agent
from wmthesis.planet.decoder import DECODER_NAME, attach_decoder


def shipped_decoder(model, planet, path: Path, saved_info: dict) -> dict | None:
    """Attach the decoder file beside the agent at ``path`` (or beside the PlaNet agent a value's
    agent plans with) to ``model``; its ``fitted_on``, or None where none ships (the model then
    refuses to decode, saying why)."""
    folders = [Path(path).parent]
    if saved_info.get("model_file"):
        folders.append((Path(path).parent / saved_info["model_file"]["path"]).parent)
    for folder in folders:
        if (folder / DECODER_NAME).is_file():
            return attach_decoder(model, planet, folder / DECODER_NAME)
    model.decoder = NoDecoder(path)
    return None


class PlanetAgent(TrainedAgent):
    """A PlaNet experiment's agent: ``model`` (the RSSM), ``planner`` (the CEM settings it plans
    with, its :class:`~wmthesis.planet.config.PlaNetConfig`) and ``value`` (None: PlaNet's own CEM)."""

    decoded = "the posterior's reconstructions and the imagined frames"
    fit_decoder = "python tools/fit_decoders.py planet"
    read = staticmethod(load_agent)  # the agent file's reader
    play_one = staticmethod(play_agent)  # one scored bout: (loaded, env seed, mind seed, frames) -> rewards

    def __init__(self, path: Path, experiment: str, variant: str | None, profile: str, seed: int):
        loaded = self.read(path)
        super().__init__(path, experiment, variant, profile, seed, loaded.info)
        self.loaded, self.config = loaded, loaded.planet
        self.model, self.game = loaded.model, loaded.info["game"]
        self.value, self.planner = getattr(loaded, "value", None), getattr(loaded, "planner", loaded.planet)
        saved = torch.load(path, weights_only=False, map_location="cpu")
        self.decoder_info = shipped_decoder(self.model, loaded.planet, path, saved)
        self.horizon = int(self.planner.horizon)
        self.shown = tuple(range(1, self.horizon + 1))  # small frames: every imagined step is decoded

    def env(self):
        """The game with PlaNet's frames ((S, S, 3) uint8 of ``config.bits`` bits, the config's
        crop and action repeat), as its bouts were played."""
        from wmthesis.planet.frames import make_planet_env

        return make_planet_env(self.info["game"], self.config)

    def mind(self, seed: int = 0):
        """The planner as it played its scored bouts, CEM's noise from ``seed``."""
        return PlanetMind.from_config(self.model, self.config, seed)

    def scored_seeds(self, bouts: int) -> list[int]:
        return [int(env_seed) for env_seed, _ in self.info["bouts"][:bouts]]

    def scored_minds(self, bouts: int) -> list[tuple[int, object]]:
        self.check_bouts(bouts)
        return [(int(env_seed), self.mind(int(mind_seed))) for env_seed, mind_seed in self.info["bouts"][:bouts]]

    @property
    def scored_bouts(self) -> int:
        return len(self.info["bouts"])

    def check_bouts(self, bouts: int) -> None:
        if bouts > len(self.info["bouts"]):
            raise ValueError(f"{self.path} was scored on {len(self.info['bouts'])} bouts, not {bouts}")

    @torch.inference_mode()
    def step_prediction(self, mind, frame, action: int) -> dict:
        """The RSSM's step from the frame filtered into the belief: the prior's mean, decoded, and its reward."""
        from wmthesis.planet.prediction import planned_path
        from wmthesis.planet.rssm import frames_out

        mind.observe(frame, **mind.observe_options)
        beliefs, states, rewards = planned_path(self.model, mind.belief, mind.state, torch.tensor([action]))
        shown = frames_out(self.model.decode(beliefs, states), self.config.bits)[0].cpu().numpy() \
            if self.decoder_info is not None else None
        return {"frame": shown, "reward": float(rewards.reshape(-1)[0])}

    @torch.inference_mode()
    def thought(self, mind):
        """What the planner chose and what the model imagines along it: the plan (the final CEM
        mean's argmax at each of its steps) rolled out from the belief on the prior's means, with
        the rewards the model predicts, decoded; CEM's final scores for the first action and its
        elite return per iteration; the posterior's reconstruction of the frame."""
        from wmthesis.planet.prediction import planned_path
        from wmthesis.planet.rssm import frames_out
        from wmthesis.thoughts import Thought

        plan = mind.last_plan
        beliefs, states, rewards = planned_path(self.model, mind.belief, mind.state, plan.mean.argmax(-1))
        thought = Thought(imagined_rewards=rewards.cpu().numpy(), scores={"plan": plan.mean[0].cpu().numpy()},
                          series={"cem_elites": plan.elites.cpu().numpy()},
                          values={"best_return": float(plan.returns.max())})
        if self.decoder_info is not None:
            frames = frames_out(self.model.decode(torch.cat([mind.belief, beliefs]), torch.cat([mind.state, states])),
                                self.config.bits).cpu().numpy()
            thought.seen, thought.imagined = frames[0], {j + 1: f for j, f in enumerate(frames[1:])}
        return thought

    def open_loop_figure(self, bouts=(0, 1, 2), start: int = 100, context: int = 5, horizon: int = 15,
                         title: str | None = None):
        """The thesis's open-loop figure (Fig. 58-511) from this agent: on each of its scored
        ``bouts``, the stretch from step ``start`` as its planner played it, ``context`` frames
        filtered, then ``horizon`` steps imagined along the actions it took, beside what came."""
        from wmthesis.planet.figures import open_loop_figure

        outs = []
        for bout in bouts:
            frames, actions = self.stretch(bout, start + context + horizon)
            outs.append(self.open_loop(frames[start:], actions[start:], context=context, seed=bout))
        result = {"truth": np.stack([o["truth"] for o in outs]), "prediction": np.stack([o["prediction"] for o in outs]),
                  "context": context}
        return open_loop_figure(result, sequences=len(outs), title=title)

    def play_bouts(self, bouts: int, frames: list | None = None, on_bout=None) -> list[dict]:
        self.check_bouts(bouts)
        plays = []
        for k, (env_seed, mind_seed) in enumerate(self.info["bouts"][:bouts]):
            shown = [] if frames is not None else None
            rewards = self.play_one(self.loaded, env_seed, mind_seed, shown)
            plays.append({"bout": k, "return": float(sum(rewards)), "steps": len(rewards)})
            if frames is not None:
                frames.append(np.stack(shown))
            if on_bout is not None:
                on_bout(plays[-1])
        return plays

    def open_loop(self, frames, actions, context: int = 5, seed: int = 0) -> dict:
        """Filter ``context`` real frames of one episode (``frames`` (T, S, S, 3) uint8 from
        :meth:`env`, ``actions`` (T,), ``actions[t]`` taken at ``frames[t]``), then imagine the rest along the actions taken from the
        prior's means: ``truth`` and ``prediction`` (T, S, S, 3) uint8 (the first ``context``
        predictions are reconstructions) and ``mse`` per imagined step."""
        from wmthesis.planet.prediction import open_loop

        frames = check_planet_frames(frames, self.config.frame_size, many=True)
        actions = torch.from_numpy(check_episode(frames, actions, context + 1, self.model.n_actions))
        generator = torch.Generator(next(self.model.parameters()).device).manual_seed(seed)
        out = open_loop(self.model, frames[None], actions[None], context=context, bits=self.config.bits,
                        generator=generator)
        return {"truth": out["truth"][0], "prediction": out["prediction"][0], "mse": out["mse"], "context": context}


def check_planet_frames(frames, size: int, many: bool = False) -> torch.Tensor:
    """PlaNet's frames as a uint8 tensor ((T,) S, S, 3); ValueError naming what was expected and
    the environment that gives it otherwise."""
    frames = frames if isinstance(frames, torch.Tensor) else torch.as_tensor(np.asarray(frames))
    shape = (size, size, 3)
    if frames.dtype != torch.uint8 or tuple(frames.shape[-3:]) != shape or frames.ndim != 3 + many:
        raise ValueError(f"this PlaNet model sees uint8 frames {('(T, ' if many else '(') + ', '.join(map(str, shape))}), "
                         f"got {frames.dtype} {tuple(frames.shape)}: `agent.env()` gives them (its frame size and crop, "
                         "not make_env's 64x64 'planet' preprocessing)")
    return frames


def load_trained(path: Path, *, experiment: str, variant: str | None, profile: str, seed: int) -> PlanetAgent:
    return PlanetAgent(path, experiment, variant, profile, seed)


__all__ = ["PlanetAgent", "load_trained", "shipped_decoder", "check_planet_frames"]
