"""The PlaNet agent (thesis 4.4): a belief filtered from the frames it sees (:class:`BeliefFilter`),
and the planner that acts on it with discrete CEM (:class:`PlanetMind`, :func:`play_greedy`)."""
from __future__ import annotations


import numpy as np
import torch
import torch.nn.functional as F

from wmthesis.core import Callback, Mind, loop
from wmthesis.envs.preprocessing import to_float
from wmthesis.planet.cem import cem_belief
from wmthesis.planet.config import PlaNetConfig
from wmthesis.planet.explore import explored_returns
from wmthesis.planet.rssm import RSSM
from wmthesis.rollouts import EpisodeBuffer


# ---------------------------------------------------------------------------- agent
class BeliefFilter(Mind, Callback):
    """An agent's belief ``(h_t, s_t)`` under an RSSM, filtered along the episode, for
    :func:`~wmthesis.core.loop`: the part that PlaNet's planner and the latent value agent
    (:class:`~wmthesis.value.latent_value.ValueMind`) share.

    Pass a subclass as the mind AND among the callbacks: ``on_episode_start`` resets the belief
    and ``on_step_taken`` records the action taken (the policy may differ from the plan).
    :meth:`reset` does the episode reset by hand.
    """

    def __init__(self, model: RSSM, bits: int = 5, generator: torch.Generator | None = None):
        self.model, self.bits = model, bits
        weight = next(model.parameters())
        self.generator = generator if generator is not None else torch.Generator(weight.device).manual_seed(0)
        self.reset()

    def reset(self) -> None:
        """Start of an episode: zero belief, state and previous action."""
        self.belief, self.state = self.model.initial(1)
        self.prev_action = self.belief.new_zeros(1, self.model.n_actions)

    def on_episode_start(self, episode, train_mode):
        self.reset()

    def on_step_taken(self, step, transition, info):
        self.prev_action = F.one_hot(torch.tensor([transition.action], device=self.belief.device),
                                     self.model.n_actions).float()

    def observe_step(self, frame: np.ndarray, action: int) -> None:
        """One step of an episode seen and taken: ``frame`` filtered into the belief, then
        ``action`` taken at it (what :func:`~wmthesis.core.loop` does through :meth:`plan` and the
        callback); the next :meth:`plan` starts from there."""
        self.observe(frame, **self.observe_options)
        self.prev_action = F.one_hot(torch.tensor([int(action)], device=self.belief.device), self.model.n_actions).float()

    observe_options: dict = {}  # how plan() observes (the value's mind takes the posterior's mean)

    @torch.inference_mode()
    def observe(self, frame: np.ndarray, sample: bool = True) -> None:
        """Advance ``(h, s)`` with a (size, size, 3) uint8 frame (``bits`` bits, dequantisation
        noise as in training) and the previous action; ``s`` is the posterior's sample, or its
        mean when not ``sample``."""
        frame = torch.as_tensor(np.asarray(frame) if not isinstance(frame, torch.Tensor) else frame)
        expected = self.model.encoder_input_shape
        if frame.dtype != torch.uint8 or (expected is not None and tuple(frame.shape) != expected):
            raise ValueError(f"this PlaNet model sees uint8 frames {expected}, got {frame.dtype} {tuple(frame.shape)}: "
                             "the agent's env() gives them (its frame size and crop)")
        x = to_float(frame.to(self.belief.device), self.bits, noise=self.generator)
        self.belief, _ = self.model.transition(self.belief, self.state, self.prev_action)
        posterior = self.model.posterior(self.belief, self.model.encode(x[None]))
        self.state = posterior.sample(self.generator) if sample else posterior.mean


class PlanetMind(BeliefFilter):
    """The PlaNet agent: filter the belief (:class:`BeliefFilter`), plan with CEM. Each
    :meth:`plan` first updates ``(h, s)`` with the observation and the previous action, then
    returns the scores of the final CEM belief for the first step (argmax = the plan's action);
    ``last_plan`` keeps that final :class:`~wmthesis.planet.cem.Belief` (H, A).
    """

    def __init__(self, model: RSSM, *, horizon: int, candidates: int, top_k: int,
                 iterations: int, bits: int = 5, generator: torch.Generator | None = None,
                 explorer=None, explore_scale: float = 0.0):
        self.sizes = dict(horizon=horizon, candidates=candidates, top_k=top_k, iterations=iterations)
        self.explorer, self.explore_scale = explorer, explore_scale
        super().__init__(model, bits, generator)

    @classmethod
    def from_config(cls, model: RSSM, config: PlaNetConfig, seed: int = 0, explorer=None) -> "PlanetMind":
        """The config's planner; with an ``explorer`` (:class:`~wmthesis.planet.explore.Disagreement`),
        the collecting planner whose returns add ``config.explore_scale`` x its disagreement."""
        generator = torch.Generator(next(model.parameters()).device).manual_seed(seed)
        return cls(model, horizon=config.horizon, candidates=config.candidates, top_k=config.top_k,
                   iterations=config.iterations, bits=config.bits, generator=generator, explorer=explorer,
                   explore_scale=config.explore_scale if explorer is not None else 0.0)

    def returns(self, actions: torch.Tensor) -> torch.Tensor:
        """CEM's objective: one-hot candidates (J, H, A) -> their imagined returns (J,) from the
        current belief (the thesis's: the sum of predicted rewards; with an explorer, plus its
        bonus: :func:`~wmthesis.planet.explore.explored_returns`)."""
        return explored_returns(self.model, self.explorer, self.explore_scale, self.belief, self.state, actions,
                                self.generator)

    def first_mean(self) -> torch.Tensor | None:
        """CEM's first mean (H, A) from the current belief; None: zeros, the thesis's."""
        return None

    @torch.inference_mode()
    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        self.observe(state)
        belief = cem_belief(self.returns, self.model.n_actions, generator=self.generator, mean=self.first_mean(),
                            **self.sizes)
        self.last_plan = belief  # what a recording shows of the plan
        scores = belief.mean[0].cpu().numpy()
        if debug_mode:
            return scores, {"std": belief.std[0].cpu().numpy(), "best_return": float(belief.returns.max())}
        return scores


def play_greedy(env, model: RSSM, config: PlaNetConfig, env_seed: int, mind_seed: int,
                frames: list | None = None) -> list[float]:
    """One greedy planner episode in ``env`` (reset with ``env_seed``; CEM's noise from
    ``mind_seed``): its rewards, one per agent step; ``frames`` (a list), where given, gets the
    episode's frames."""
    mind = PlanetMind.from_config(model, config, int(mind_seed))
    record = EpisodeBuffer()
    loop(env, mind, policy="deterministic", callbacks=[mind, record], seed=int(env_seed), train_mode=False)
    if frames is not None:
        frames += list(record.episode["observations"])
    return [float(r) for r in record.episode["rewards"]]


__all__ = ["BeliefFilter", "PlanetMind", "play_greedy"]
