"""PlaNet's recurrent state-space model, RSSM (thesis 3.2, 4.4.1, 4.4.5), and its loss.

The state at time t has a deterministic part ``h_t`` (the belief, a GRU of 200 units) and a
stochastic part ``s_t`` (a 30-dimensional diagonal Gaussian)::

    h_t = f(h_{t-1}, s_{t-1}, a_{t-1})     GRU on relu(FC([s_{t-1}, one_hot(a_{t-1})]))
    p(s_t | h_t)                           prior: FC 200 + ReLU, FC -> mean, std
    q(s_t | h_t, o_t)                      posterior: FC 200 + ReLU on [h_t, encoder(o_t)]
    p(o_t | h_t, s_t) = N(decoder([h_t, s_t]), decoder_variance I)
    p(r_t | h_t, s_t) = N(reward([h_t, s_t]), 1)  FF with two hidden layers of 100

Standard deviations are ``softplus(x) + min_std`` (0.1, as the official code). The encoder and
decoder are the World Models VAE's convolutional networks (:mod:`wmthesis.world_models.vision`); the
decoder's raw output is the mean of the Gaussian over pixels. Observations are 5-bit frames
turned into floats in [-0.5, 0.5) by :func:`~wmthesis.envs.preprocessing.to_float`, with
uniform dequantisation noise when training.

Time indexing follows the episode store: row t of a chunk holds ``o_t``, ``a_t`` and
``r_{t+1}``. The model sees ``o_t`` together with the previous action ``a_{t-1}`` (zeros at
the first step of a chunk, whose state starts at zeros), and the reward predicted from
``(h_t, s_t)`` is the reward of arriving there, ``r_t``: row ``t - 1`` of the chunk.

Loss (:func:`planet_loss`), normalised as the official code (``compute_losses``): every term
is summed over its features (pixels, latent dimensions) and averaged over batch and time;
free nats clip each KL term from below, ``max(free_nats, KL)`` per (batch, time) element::

    loss = obs_nll + reward_scale * (reward_nll + prior_reward_scale * prior_reward_nll
                                     + overshooting_reward_scale * overshooting_reward)
           + kl_scale * (mean max(free_nats, KL[q(s_t) || p(s_t | h_t)])
                         + overshooting_scale * overshooting)

Latent overshooting (thesis 3.2, Fig. 34c) rolls the prior open-loop from every posterior for
distances d = 2..D (d = 1 is the standard KL term) and adds ``max(free_nats, KL[q(s_t) ||
p(s_t | s_{t-d})])`` with the posterior's gradient stopped; the term is averaged over batch,
time and distances (the official code's layout) and scaled by ``overshooting_scale`` (1/50).
Beyond the thesis, ``overshooting_reward_scale`` (0 in the thesis; the knob of Kaixhin's PyTorch
PlaNet) also trains the reward head on the open-loop beliefs (with the prior's mean), the states
the planner's rollouts reach: a model trained on filtered states alone can name a reward it
sees in a frame and still not predict one. Two more knobs beyond the thesis, for games where a
reward is rare (2.9% of random Boxing steps): ``prior_reward_scale`` trains the reward head on
the one-step prior states ``(h_t, mean of p(s_t | h_t))`` as well, the planner's first imagined
step, and ``reward_event_weight`` makes each step with a non-zero reward count that many times
in the weighted mean of every reward term, the open-loop one included (1: the plain mean).

Decoder variance (thesis 5.6.3). With ``log p(o | z) = -0.5 ||o - f(z)||^2 / sigma^2 - log Z``,
multiplying the whole loss by ``sigma^2`` gives ``0.5 ||o - f(z)||^2 + sigma^2 * kl_scale * KL
+ sigma^2 * reward_scale * reward_nll`` plus constants: the loss with decoder variance 1, KL
scale ``sigma^2 * kl_scale`` and reward scale ``sigma^2 * reward_scale``. The two objectives
differ in value (the normaliser Z) and by a constant factor, so their gradients are
proportional and Adam, invariant to a constant loss scale up to its epsilon, takes the same
steps: lowering the decoder variance IS lowering the KL scale (and the reward scale with it;
``tests/test_planet.py`` checks the gradients).
"""
from __future__ import annotations

import math
from typing import Callable, Iterator, NamedTuple

import torch
import torch.nn.functional as F
from torch import nn

from wmthesis.envs.preprocessing import to_float, to_uint8
from wmthesis.world_models.vision import Decoder, Encoder

EMBEDDING_SIZE = 1024  # the VAE encoder's features


def bottle(fn: Callable, *tensors: torch.Tensor) -> torch.Tensor:
    """Apply ``fn`` to tensors of shape (B, T, ...) with time folded into the batch.

    ``fn`` sees (B * T, ...) tensors; each tensor of its output (a tensor or a possibly
    nested tuple or named tuple of them), (B * T, ...), comes back as (B, T, ...).
    """
    batch, time = tensors[0].shape[:2]
    return _unfold(fn(*(x.reshape(batch * time, *x.shape[2:]) for x in tensors)), batch, time)


def _unfold(out, batch: int, time: int):
    if isinstance(out, torch.Tensor):
        return out.reshape(batch, time, *out.shape[1:])
    items = [_unfold(item, batch, time) for item in out]
    return type(out)(*items) if hasattr(out, "_fields") else type(out)(items)


def randn_like(x: torch.Tensor, generator: torch.Generator | None = None) -> torch.Tensor:
    """Standard normal noise with the shape, dtype and device of ``x``."""
    return torch.randn(x.shape, generator=generator, device=x.device, dtype=x.dtype)


class Gaussian(NamedTuple):
    """A diagonal Gaussian: ``mean`` and ``std``, each (..., S)."""

    mean: torch.Tensor
    std: torch.Tensor

    def sample(self, generator: torch.Generator | None = None) -> torch.Tensor:
        """One reparameterised sample (..., S)."""
        return self.mean + self.std * randn_like(self.mean, generator)


class Trajectory(NamedTuple):
    """A filtered sequence: ``beliefs`` (B, T, H), ``states`` (B, T, S) posterior samples,
    ``prior`` and ``posterior`` Gaussians over ``s_t``, each (B, T, S)."""

    beliefs: torch.Tensor
    states: torch.Tensor
    prior: Gaussian
    posterior: Gaussian


def one_hot_previous(actions: torch.Tensor, n_actions: int) -> torch.Tensor:
    """Actions (B, T) long -> previous actions one-hot (B, T, A): row t is ``a_{t-1}``,
    zeros at t = 0."""
    one_hot = F.one_hot(actions, n_actions).float()
    return torch.cat([torch.zeros_like(one_hot[:, :1]), one_hot[:, :-1]], 1)


class RSSM(nn.Module):
    """The recurrent state-space model (module docstring), thesis sizes by default.

    ``encoder``/``decoder`` default to the VAE's convolutional networks for (64, 64, 3)
    frames; any modules mapping (N, 3, H, W) -> (N, ``embedding_size``) and
    (N, belief_size + state_size) -> (N, 3, H, W) fit (the tests use small ones).
    """

    def __init__(self, n_actions: int, belief_size: int = 200, state_size: int = 30,
                 hidden_size: int = 200, reward_hidden_size: int = 100, min_std: float = 0.1,
                 encoder: nn.Module | None = None, decoder: nn.Module | None = None,
                 embedding_size: int = EMBEDDING_SIZE):
        super().__init__()
        self.n_actions, self.belief_size, self.state_size = n_actions, belief_size, state_size
        self.embedding_size = embedding_size
        self.min_std = min_std
        self.encoder = encoder if encoder is not None else Encoder()
        self.decoder = decoder if decoder is not None else Decoder(belief_size + state_size)
        self.embed_state_action = nn.Linear(state_size + n_actions, belief_size)
        self.gru = nn.GRUCell(belief_size, belief_size)
        self.prior_net = _two_layers(belief_size, hidden_size, 2 * state_size)
        self.posterior_net = _two_layers(belief_size + embedding_size, hidden_size, 2 * state_size)
        self.reward_net = nn.Sequential(
            nn.Linear(belief_size + state_size, reward_hidden_size), nn.ReLU(),
            nn.Linear(reward_hidden_size, reward_hidden_size), nn.ReLU(),
            nn.Linear(reward_hidden_size, 1))

    @property
    def encoder_input_shape(self) -> tuple[int, int, int] | None:
        """The (S, S, 3) frames the encoder sees, where it says (None: any)."""
        size = getattr(self.encoder, "frame_size", None)
        return None if size is None else (size, size, 3)

    # ------------------------------------------------------------------ one step
    def initial(self, batch: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Zero belief (batch, H) and state (batch, S) on the model's device."""
        weight = self.embed_state_action.weight
        return weight.new_zeros(batch, self.belief_size), weight.new_zeros(batch, self.state_size)

    def transition(self, belief: torch.Tensor, state: torch.Tensor,
                   action: torch.Tensor) -> tuple[torch.Tensor, Gaussian]:
        """``h_{t-1}`` (N, H), ``s_{t-1}`` (N, S), one-hot ``a_{t-1}`` (N, A) -> ``h_t`` (N, H)
        and the prior ``p(s_t | h_t)`` (N, S)."""
        hidden = F.relu(self.embed_state_action(torch.cat([state, action], -1)))
        belief = self.gru(hidden, belief)
        return belief, self._gaussian(self.prior_net(belief))

    def posterior(self, belief: torch.Tensor, embedding: torch.Tensor) -> Gaussian:
        """``h_t`` (N, H) and ``encoder(o_t)`` (N, E) -> ``q(s_t | h_t, o_t)`` (N, S)."""
        return self._gaussian(self.posterior_net(torch.cat([belief, embedding], -1)))

    def _gaussian(self, out: torch.Tensor) -> Gaussian:
        mean, std = out.chunk(2, -1)
        return Gaussian(mean, F.softplus(std) + self.min_std)

    # ------------------------------------------------------------------ heads (any leading dims)
    def encode(self, frames: torch.Tensor) -> torch.Tensor:
        """Float frames (..., H, W, 3) in [-0.5, 0.5) -> embeddings (..., E)."""
        lead = frames.shape[:-3]
        x = frames.reshape(-1, *frames.shape[-3:]).movedim(-1, -3)
        return self.encoder(x).reshape(*lead, -1)

    def decode(self, belief: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """``h`` (..., H), ``s`` (..., S) -> mean frames (..., H_img, W_img, 3)."""
        features = torch.cat([belief, state], -1)
        lead = features.shape[:-1]
        out = self.decoder(features.reshape(-1, features.shape[-1])).movedim(-3, -1)
        return out.reshape(*lead, *out.shape[1:])

    def reward(self, belief: torch.Tensor, state: torch.Tensor) -> torch.Tensor:
        """``h`` (..., H), ``s`` (..., S) -> mean reward (...)."""
        return self.reward_net(torch.cat([belief, state], -1)).squeeze(-1)

    # ------------------------------------------------------------------ sequences
    def observe(self, embeddings: torch.Tensor, prev_actions: torch.Tensor,
                generator: torch.Generator | None = None,
                start: tuple[torch.Tensor, torch.Tensor] | None = None) -> Trajectory:
        """Filter a sequence: embeddings (B, T, E), previous actions one-hot (B, T, A), an
        optional start ``(h, s)`` (each (B, .), zeros by default) -> :class:`Trajectory`."""
        belief, state = start if start is not None else self.initial(embeddings.shape[0])
        beliefs, states, priors, posteriors = [], [], [], []
        for t in range(embeddings.shape[1]):
            belief, prior = self.transition(belief, state, prev_actions[:, t])
            posterior = self.posterior(belief, embeddings[:, t])
            state = posterior.sample(generator)
            beliefs.append(belief)
            states.append(state)
            priors.append(prior)
            posteriors.append(posterior)
        stack = lambda xs: torch.stack(xs, 1)  # noqa: E731
        return Trajectory(stack(beliefs), stack(states),
                          Gaussian(*map(stack, zip(*priors))), Gaussian(*map(stack, zip(*posteriors))))

    def imagined_steps(self, belief: torch.Tensor, state: torch.Tensor, actions: torch.Tensor,
                       pick: Callable[[Gaussian], torch.Tensor]) -> Iterator["ImaginedStep"]:
        """The one loop that imagines paths: from ``(h, s)`` (1 or N, H), (1 or N, S) along one-hot
        ``actions`` (N, T, A), one :class:`ImaginedStep` per step, batched over the N paths.
        Step t's state is ``pick(prior)`` (e.g. ``prior.sample(generator)``), picked only when
        read, so a caller that stops before reading the last one draws no noise for it."""
        count = actions.shape[0]
        belief, state = belief.expand(count, -1), state.expand(count, -1)
        for t in range(actions.shape[1]):
            before = (belief, state)
            belief, prior = self.transition(belief, state, actions[:, t])
            step = ImaginedStep(t, before, belief, prior, pick)
            yield step
            state = step.state

    def imagine(self, belief: torch.Tensor, state: torch.Tensor, actions: torch.Tensor,
                generator: torch.Generator | None = None,
                sample: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """Open-loop prediction from ``(h, s)`` (N, H), (N, S) under one-hot actions
        (N, T, A): returns beliefs (N, T, H) and states (N, T, S), where step t follows
        ``actions[:, t]``. ``sample=False`` follows the prior means."""
        pick = (lambda prior: prior.sample(generator)) if sample else (lambda prior: prior.mean)
        steps = [(step.belief, step.state) for step in self.imagined_steps(belief, state, actions, pick)]
        return torch.stack([b for b, _ in steps], 1), torch.stack([s for _, s in steps], 1)

    def imagined_returns(self, belief: torch.Tensor, state: torch.Tensor, actions: torch.Tensor,
                         generator: torch.Generator | None = None) -> torch.Tensor:
        """Sum of predicted rewards along one sampled trajectory per action sequence.

        ``belief`` (1 or J, H), ``state`` (1 or J, S), one-hot ``actions`` (J, T, A) ->
        returns (J,). All J sequences advance together, one batched step per time step
        (the CEM planner's objective).
        """
        total = actions.new_zeros(actions.shape[0])
        for step in self.imagined_steps(belief, state, actions, lambda prior: prior.sample(generator)):
            total = total + self.reward(step.belief, step.state)
        return total


class ImaginedStep:
    """Step ``t`` of imagined paths (:meth:`RSSM.imagined_steps`): ``before``, the ``(h, s)`` the
    step's action is taken in; ``belief`` h_t and ``prior`` p(s_t | h_t) after it; ``state``
    s_t, picked from the prior when first read."""

    def __init__(self, t: int, before: tuple[torch.Tensor, torch.Tensor], belief: torch.Tensor, prior: Gaussian,
                 pick: Callable[[Gaussian], torch.Tensor]):
        self.t, self.before, self.belief, self.prior, self._pick, self._state = t, before, belief, prior, pick, None

    @property
    def state(self) -> torch.Tensor:
        if self._state is None:
            self._state = self._pick(self.prior)
        return self._state


def _two_layers(inputs: int, hidden: int, outputs: int) -> nn.Sequential:
    return nn.Sequential(nn.Linear(inputs, hidden), nn.ReLU(), nn.Linear(hidden, outputs))


# ---------------------------------------------------------------------------- loss
def gaussian_nll(x: torch.Tensor, mean: torch.Tensor, variance: float, dims: int) -> torch.Tensor:
    """``-log N(x; mean, variance I)`` summed over the last ``dims`` dimensions."""
    nll = 0.5 * (x - mean).pow(2) / variance + 0.5 * math.log(2 * math.pi * variance)
    return nll.flatten(-dims).sum(-1)


def kl_divergence(q: Gaussian, p: Gaussian) -> torch.Tensor:
    """``KL(q || p)`` of diagonal Gaussians, summed over the last dimension: (..., S) -> (...)."""
    ratio = (q.std / p.std).pow(2)
    return 0.5 * (ratio + ((q.mean - p.mean) / p.std).pow(2) - 1 - ratio.log()).sum(-1)


def reward_nll(model: RSSM, beliefs: torch.Tensor, states: torch.Tensor, rewards: torch.Tensor,
               event_weight: float = 1.0) -> torch.Tensor:
    """NLL of the reward of arriving at ``(h_t, s_t)``, beliefs (B, T, H) and states (B, T, S),
    against ``rewards`` (B, T) whose row t holds ``r_{t+1}`` (so t = 1..T-1 are scored): a
    weighted mean over batch and time where a step with a non-zero reward weighs ``event_weight``
    and any other step 1."""
    return _weighted_reward_nll(model.reward(beliefs[:, 1:], states[:, 1:]), rewards[:, :-1], event_weight)


def _weighted_reward_nll(predicted: torch.Tensor, target: torch.Tensor, event_weight: float) -> torch.Tensor:
    """Unit-variance Gaussian NLL of ``target`` (B, T') under ``predicted`` (B, T'), a mean in which
    a non-zero target weighs ``event_weight`` and a zero one 1."""
    nll = gaussian_nll(target[..., None], predicted[..., None], 1.0, dims=1)
    weight = torch.where(target != 0, event_weight, 1.0)
    return (weight * nll).sum() / weight.sum()


def overshooting_terms(model: RSSM, trajectory: Trajectory, prev_actions: torch.Tensor, rewards: torch.Tensor,
                       distance: int, free_nats: float, noise: torch.Tensor,
                       event_weight: float = 1.0) -> tuple[torch.Tensor, torch.Tensor]:
    """Latent overshooting terms, each a mean over distances d = 2..D of a mean over batch and
    time: ``max(free_nats, KL[q(s_t) || p(s_t | s_{t-d})])`` (posteriors detached), and the
    reward NLL of ``r_t`` predicted from the open-loop belief and the prior's mean, where a
    non-zero ``r_t`` weighs ``event_weight`` (:func:`reward_nll`'s weighting).

    Open-loop rollouts start from every one-step prior ``p(s_i | h_i)`` (the posterior at
    ``i - 1`` followed by ``a_{i-1}``), one per i = 0..T-1, all in one batch that shrinks by
    one start per step, so that step k (d = k) covers the starts i = 0..T-k with target
    ``t = i + k - 1``. ``noise`` (D - 1, B, T, S): ``noise[k - 1][:, i]`` is the standard
    normal of the prior sample after step k from start i. ``rewards`` (B, T): row t holds
    ``r_{t+1}``. ``D = min(distance, T)``; zeros when D < 2.
    """
    time = prev_actions.shape[1]
    distance = min(distance, time)
    if distance < 2:
        zero = trajectory.beliefs.new_zeros(())
        return zero, zero
    target = Gaussian(trajectory.posterior.mean.detach(), trajectory.posterior.std.detach())
    belief, prior = trajectory.beliefs, trajectory.prior
    kls, reward_nlls = [], []
    for k in range(2, distance + 1):
        starts = time - k + 1
        state = prior.mean[:, :starts] + prior.std[:, :starts] * noise[k - 2][:, :starts]
        belief, prior = bottle(model.transition, belief[:, :starts], state, prev_actions[:, k - 1:])
        kl = kl_divergence(Gaussian(target.mean[:, k - 1:], target.std[:, k - 1:]), prior)
        kls.append(kl.clamp(min=free_nats).mean())
        reward_nlls.append(_weighted_reward_nll(model.reward(belief, prior.mean), rewards[:, k - 2:time - 1],
                                                event_weight))
    return torch.stack(kls).mean(), torch.stack(reward_nlls).mean()


def planet_loss(model: RSSM, observations: torch.Tensor, actions: torch.Tensor,
                rewards: torch.Tensor, *, bits: int = 5, kl_scale: float = 1.0,
                free_nats: float = 3.0, decoder_variance: float = 1.0, reward_scale: float = 1.0,
                overshooting_distance: int = 0, overshooting_scale: float = 1 / 50,
                overshooting_reward_scale: float = 0.0, prior_reward_scale: float = 0.0,
                reward_event_weight: float = 1.0,
                generator: torch.Generator | None = None) -> dict[str, torch.Tensor]:
    """The PlaNet loss on a batch of chunks (module docstring). The defaults here are a plain
    ELBO; :class:`~wmthesis.planet.config.PlaNetConfig` holds the thesis's values.

    ``observations`` (B, T, H, W, 3) uint8 (``bits``-bit values), ``actions`` (B, T) long,
    ``rewards`` (B, T) with row t the reward ``r_{t+1}``; all on the model's device.
    ``generator`` draws, in this order, the dequantisation noise (:func:`to_float`), the
    posterior samples (:meth:`RSSM.observe`) and the overshooting noise (D - 1, B, T, S).
    Returns scalars: ``loss``, ``observation`` (Gaussian NLL), ``reward`` and ``prior_reward``
    (:func:`reward_nll` of the filtered and the one-step prior states), ``kl``
    (unclipped mean), ``kl_loss`` (clipped mean), ``overshooting`` and ``overshooting_reward``
    (:func:`overshooting_terms`), ``observation_mse``
    (per pixel).
    """
    frames = to_float(observations, bits, noise=generator)
    prev_actions = one_hot_previous(actions, model.n_actions)
    trajectory = model.observe(model.encode(frames), prev_actions, generator)
    noise = None
    if overshooting_distance >= 2 and frames.shape[1] >= 2:
        steps = min(overshooting_distance, frames.shape[1]) - 1
        noise = torch.randn((steps, *trajectory.states.shape), generator=generator,
                            device=frames.device, dtype=frames.dtype)
    return loss_terms(model, trajectory, frames, prev_actions, rewards, kl_scale=kl_scale,
                      free_nats=free_nats, decoder_variance=decoder_variance,
                      reward_scale=reward_scale, overshooting_distance=overshooting_distance,
                      overshooting_scale=overshooting_scale, overshooting_reward_scale=overshooting_reward_scale,
                      overshooting_noise=noise, prior_reward_scale=prior_reward_scale,
                      reward_event_weight=reward_event_weight)


def loss_terms(model: RSSM, trajectory: Trajectory, frames: torch.Tensor, prev_actions: torch.Tensor,
               rewards: torch.Tensor, *, kl_scale: float, free_nats: float, decoder_variance: float,
               reward_scale: float, overshooting_distance: int, overshooting_scale: float,
               overshooting_noise: torch.Tensor | None,
               overshooting_reward_scale: float = 0.0, prior_reward_scale: float = 0.0,
               reward_event_weight: float = 1.0) -> dict[str, torch.Tensor]:
    """:func:`planet_loss` given the filtered ``trajectory`` of float ``frames``
    (B, T, H, W, 3) and the overshooting noise (see :func:`overshooting_terms`)."""
    if reward_event_weight <= 0 or prior_reward_scale < 0:
        raise ValueError(f"reward_event_weight must be > 0 and prior_reward_scale >= 0, got "
                         f"{reward_event_weight} and {prior_reward_scale}")
    mean_frames = model.decode(trajectory.beliefs, trajectory.states)
    observation = gaussian_nll(frames, mean_frames, decoder_variance, dims=3).mean()
    reward = reward_nll(model, trajectory.beliefs, trajectory.states, rewards, reward_event_weight)
    prior_reward = trajectory.beliefs.new_zeros(())
    if prior_reward_scale:
        prior_reward = reward_nll(model, trajectory.beliefs, trajectory.prior.mean, rewards, reward_event_weight)
    kl = kl_divergence(trajectory.posterior, trajectory.prior)
    kl_loss = kl.clamp(min=free_nats).mean()
    overshooting = overshooting_reward = trajectory.beliefs.new_zeros(())
    if overshooting_noise is not None:
        overshooting, overshooting_reward = overshooting_terms(model, trajectory, prev_actions, rewards,
                                                               overshooting_distance, free_nats, overshooting_noise,
                                                               reward_event_weight)
    loss = (observation + reward_scale * (reward + prior_reward_scale * prior_reward
                                          + overshooting_reward_scale * overshooting_reward)
            + kl_scale * (kl_loss + overshooting_scale * overshooting))
    return {"loss": loss, "observation": observation, "reward": reward, "prior_reward": prior_reward, "kl": kl.mean(),
            "kl_loss": kl_loss, "overshooting": overshooting, "overshooting_reward": overshooting_reward,
            "observation_mse": (frames - mean_frames).pow(2).mean().detach()}


# ---------------------------------------------------------------------------- frames
def frames_out(mean_frames: torch.Tensor, bits: int = 5) -> torch.Tensor:
    """Decoded float frames (..., H, W, 3) -> ``bits``-bit uint8 frames, as PlaNet's
    ``postprocess`` (values outside [-0.5, 0.5) are clipped)."""
    return to_uint8(mean_frames.clamp(-0.5, 0.5 - 2.0 ** -bits), bits)


__all__ = ["RSSM", "Gaussian", "Trajectory", "bottle", "one_hot_previous", "planet_loss",
           "loss_terms", "reward_nll", "overshooting_terms", "kl_divergence", "gaussian_nll", "frames_out",
           "EMBEDDING_SIZE", "ImaginedStep"]
