"""HumbleRL core (thesis 4.1): the interfaces between an agent and an environment.

- A :class:`Mind` plans: given a state it returns a 1-D array of action scores (or
  ``(scores, info)``).
- An :class:`Interpreter` preprocesses ``(state, reward)`` before the mind sees them;
  :class:`ChainInterpreter` joins several into a pipeline.
- A :class:`Callback` reacts to the loop's six events; :class:`CallbackList` forwards them.
- A *policy* turns scores into an action: ``deterministic`` (argmax), ``stochastic``
  (softmax with temperature), ``proportional`` (to the scores, e.g. visit counts, for
  ``warmup`` steps, then argmax) and ``epsilon-greedy`` (with decay).
- :func:`loop` runs episodes on any gymnasium environment; :func:`pool` runs several jobs
  in worker processes.
- :class:`MDP` is the protocol through which planners (MCTS) see a model.

Faults of the original that are fixed here, each with a test: an episode cut by
``max_steps`` now fires ``on_episode_end``; ``loop`` runs exactly ``max_steps`` steps, not
one more; unknown keyword arguments raise ``TypeError``; ``proportional`` with ``warmup=0``
is an error instead of silently becoming deterministic.
"""
from __future__ import annotations

import multiprocessing as mp
from dataclasses import dataclass
from typing import Any, Callable, Protocol, Sequence, runtime_checkable

import numpy as np
from tqdm import tqdm

from wmthesis.utils import check_choice, derive_seeds, seed_everything


@dataclass(frozen=True)
class Transition:
    """One step: ``state`` --``action``--> ``next_state`` with ``reward``.

    ``is_terminal`` is the environment's *terminated* flag: a truncated episode (time limit,
    ``max_steps``) is not terminal, so its last state may still be bootstrapped.
    """

    state: Any
    action: int
    reward: float
    next_state: Any
    is_terminal: bool


class Mind:
    """An agent's planning logic. Subclasses implement :meth:`plan`."""

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        """Return action scores, a 1-D array of shape (n_actions,), or ``(scores, info)``."""
        raise NotImplementedError


class RandomMind(Mind):
    """Uniformly random scores, so any argmax-like policy picks a uniform random action."""

    def __init__(self, n_actions: int, seed: int | np.random.SeedSequence | None = None):
        self.n_actions = int(n_actions)
        self.rng = np.random.default_rng(seed)

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False) -> np.ndarray:
        return self.rng.random(self.n_actions)


class ConstantMind(Mind):
    """The same action at every step: a reference policy (Freeway's "always up"), not an agent."""

    def __init__(self, n_actions: int, action: int):
        if not 0 <= action < n_actions:
            raise ValueError(f"action must be in [0, {n_actions}), got {action}")
        self.scores = np.eye(n_actions)[action]

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False) -> np.ndarray:
        return self.scores


class Interpreter:
    """Preprocesses what the environment returns: ``(state, reward) -> (state, reward)``.

    ``state_fn`` and ``reward_fn`` default to the identity.
    """

    def __init__(self, state_fn: Callable | None = None, reward_fn: Callable | None = None):
        self.state_fn = state_fn
        self.reward_fn = reward_fn

    def __call__(self, state, reward=0.0):
        if self.state_fn is not None:
            state = self.state_fn(state)
        if self.reward_fn is not None:
            reward = self.reward_fn(reward)
        return state, reward


class ChainInterpreter(Interpreter):
    """Applies interpreters in order, each one taking the previous one's output."""

    def __init__(self, *interpreters: Interpreter):
        super().__init__()
        self.interpreters = interpreters

    def __call__(self, state, reward=0.0):
        for interpreter in self.interpreters:
            state, reward = interpreter(state, reward)
        return state, reward


class Callback:
    """Reacts to the events of :func:`loop`. Every event is a no-op unless overridden."""

    def on_loop_start(self) -> None:
        pass

    def on_loop_end(self, is_aborted: bool) -> None:
        pass

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        pass

    def on_episode_end(self, episode: int, train_mode: bool) -> None:
        pass

    def on_action_planned(self, step: int, scores: np.ndarray, info: Any) -> None:
        pass

    def on_step_taken(self, step: int, transition: Transition, info: dict) -> None:
        pass

    @property
    def metrics(self) -> dict:
        """Metrics of the episode that just ended, merged into :func:`loop`'s history."""
        return {}


class CallbackList(Callback):
    """Forwards every event to its callbacks, in order, and merges their metrics."""

    def __init__(self, callbacks: Sequence[Callback] = ()):
        self.callbacks = list(callbacks)

    def on_loop_start(self):
        for callback in self.callbacks:
            callback.on_loop_start()

    def on_loop_end(self, is_aborted):
        for callback in self.callbacks:
            callback.on_loop_end(is_aborted)

    def on_episode_start(self, episode, train_mode):
        for callback in self.callbacks:
            callback.on_episode_start(episode, train_mode)

    def on_episode_end(self, episode, train_mode):
        for callback in self.callbacks:
            callback.on_episode_end(episode, train_mode)

    def on_action_planned(self, step, scores, info):
        for callback in self.callbacks:
            callback.on_action_planned(step, scores, info)

    def on_step_taken(self, step, transition, info):
        for callback in self.callbacks:
            callback.on_step_taken(step, transition, info)

    @property
    def metrics(self) -> dict:
        merged = {}
        for callback in self.callbacks:
            merged.update(callback.metrics)
        return merged


@runtime_checkable
class MDP(Protocol):
    """What a planner sees of a model: a deterministic transition function.

    ``action_space`` is a ``gymnasium.spaces.Discrete``.
    """

    action_space: Any

    def transition(self, state, action: int) -> tuple[Any, float]:
        """Return ``(next_state, reward)``."""

    def is_terminal(self, state) -> bool:
        """Whether no action can be taken in ``state``."""


# ----------------------------------------------------------------------------- policies
class Policy:
    """Turns a mind's scores into an action. ``step`` is the step within the episode."""

    def __call__(self, scores: np.ndarray, step: int, rng: np.random.Generator) -> int:
        raise NotImplementedError


class Deterministic(Policy):
    """The action with the highest score (the first one on ties)."""

    def __call__(self, scores, step, rng):
        return int(np.argmax(scores))


@dataclass
class Stochastic(Policy):
    """Sample from ``softmax(scores / temperature)``."""

    temperature: float = 1.0

    def __post_init__(self):
        if self.temperature <= 0:
            raise ValueError(f"temperature must be positive, got {self.temperature}")

    def __call__(self, scores, step, rng):
        logits = np.asarray(scores, dtype=np.float64) / self.temperature
        probs = np.exp(logits - logits.max())
        return int(rng.choice(len(probs), p=probs / probs.sum()))


@dataclass
class Proportional(Policy):
    """Sample in proportion to non-negative scores (e.g. MCTS visit counts).

    For the first ``warmup`` steps of each episode, then greedy; ``warmup=None`` samples
    throughout. ``warmup=0`` is rejected: it would be the deterministic policy in disguise.
    All-zero scores are sampled uniformly.
    """

    warmup: int | None = None

    def __post_init__(self):
        if self.warmup is not None and self.warmup < 1:
            raise ValueError(f"warmup must be >= 1 or None (always proportional), got {self.warmup}; "
                             "for a greedy policy use policy='deterministic'")

    def __call__(self, scores, step, rng):
        if self.warmup is not None and step >= self.warmup:
            return int(np.argmax(scores))
        weights = np.asarray(scores, dtype=np.float64)
        if np.any(weights < 0):
            raise ValueError("proportional policy needs non-negative scores")
        total = weights.sum()
        probs = weights / total if total > 0 else np.full(len(weights), 1 / len(weights))
        return int(rng.choice(len(probs), p=probs))


@dataclass
class EpsilonGreedy(Policy):
    """A uniform random action with probability epsilon, else argmax.

    Epsilon decays multiplicatively by ``decay`` after every call, down to ``min_epsilon``.
    """

    epsilon: float = 0.1
    decay: float = 1.0
    min_epsilon: float = 0.0

    def __post_init__(self):
        if not 0 <= self.min_epsilon <= self.epsilon <= 1:
            raise ValueError(f"need 0 <= min_epsilon <= epsilon <= 1, got {self.min_epsilon}, {self.epsilon}")
        if not 0 < self.decay <= 1:
            raise ValueError(f"decay must be in (0, 1], got {self.decay}")

    def __call__(self, scores, step, rng):
        explore = rng.random() < self.epsilon
        self.epsilon = max(self.min_epsilon, self.epsilon * self.decay)
        return int(rng.integers(len(scores))) if explore else int(np.argmax(scores))


POLICIES = {"deterministic": Deterministic, "stochastic": Stochastic,
            "proportional": Proportional, "epsilon-greedy": EpsilonGreedy}


def make_policy(policy: str | Policy, **options) -> Policy:
    """A policy by name (``deterministic``, ``stochastic``, ``proportional``,
    ``epsilon-greedy``) with its options, or a :class:`Policy` instance as is."""
    if isinstance(policy, Policy):
        if options:
            raise TypeError("policy options are only accepted with a policy name")
        return policy
    check_choice("policy", policy, POLICIES)
    return POLICIES[policy](**options)


# ----------------------------------------------------------------------------- loop
def _split_plan(output) -> tuple[np.ndarray, Any]:
    if isinstance(output, tuple):
        scores, info = output
        return np.asarray(scores), info
    return np.asarray(output), None


def loop(env, mind: Mind, interpreter: Interpreter | None = None, *, n_episodes: int = 1,
         max_steps: int | None = None, policy: str | Policy = "deterministic",
         policy_options: dict | None = None, callbacks: Sequence[Callback] | None = None,
         train_mode: bool = True, debug_mode: bool = False, seed: int | None = None,
         progress: bool = False) -> list[dict]:
    """Run ``n_episodes`` episodes of ``mind`` in the gymnasium ``env``.

    Each step: the mind plans on the interpreted state, the policy picks an action, the
    environment steps, the interpreter preprocesses the next state and reward. An episode
    ends when the environment terminates or truncates, or after ``max_steps`` steps
    (exactly that many). ``seed`` seeds the first ``env.reset`` and the policy's sampling.

    Returns the history: one dict per episode with ``episode``, ``return``, ``steps``,
    ``terminated``, ``truncated`` and the callbacks' metrics. ``on_loop_end`` gets
    ``is_aborted=True`` if an exception (e.g. Ctrl-C) stopped the loop; it is re-raised.
    """
    if n_episodes < 1:
        raise ValueError(f"n_episodes must be >= 1, got {n_episodes}")
    if max_steps is not None and max_steps < 1:
        raise ValueError(f"max_steps must be >= 1 or None, got {max_steps}")
    interpreter = interpreter or Interpreter()
    policy = make_policy(policy, **(policy_options or {}))
    callbacks = CallbackList(callbacks or [])
    rng = np.random.default_rng(seed)
    history: list[dict] = []
    callbacks.on_loop_start()
    aborted = True
    try:
        for episode in tqdm(range(n_episodes), desc="episodes", disable=not progress):
            reset_seed = seed if episode == 0 else None
            history.append(_episode(env, mind, interpreter, policy, callbacks, rng, episode,
                                    max_steps, train_mode, debug_mode, reset_seed))
        aborted = False
    finally:
        callbacks.on_loop_end(aborted)
    return history


def _episode(env, mind, interpreter, policy, callbacks, rng, episode, max_steps,
             train_mode, debug_mode, reset_seed) -> dict:
    """Run one episode; return its history entry."""
    observation, _ = env.reset(seed=reset_seed)
    state, _ = interpreter(observation, 0.0)
    callbacks.on_episode_start(episode, train_mode)
    total, step, terminated, truncated = 0.0, 0, False, False
    while not (terminated or truncated):
        scores, plan_info = _split_plan(mind.plan(state, train_mode, debug_mode))
        callbacks.on_action_planned(step, scores, plan_info)
        action = policy(scores, step, rng)
        observation, reward, terminated, truncated, info = env.step(action)
        next_state, reward = interpreter(observation, reward)
        truncated = bool(truncated) or (max_steps is not None and step + 1 >= max_steps and not terminated)
        transition = Transition(state, action, float(reward), next_state, bool(terminated))
        callbacks.on_step_taken(step, transition, {**info, "truncated": truncated})
        total += float(reward)
        state = next_state
        step += 1
    callbacks.on_episode_end(episode, train_mode)
    return {"episode": episode, "return": total, "steps": step, "terminated": bool(terminated),
            "truncated": truncated, **callbacks.metrics}


# ----------------------------------------------------------------------------- pool
_POOL_JOB: dict = {}


def _job_seed(seed: int, job: int) -> int:
    """A well-mixed 32-bit seed for job ``job`` of a pool seeded with ``seed``."""
    return int(derive_seeds(seed, job)[0])


def _init_worker(spec: dict) -> None:
    import torch

    torch.set_num_threads(1)
    _POOL_JOB.update(spec)


def _run_job(job: int) -> list[dict]:
    spec = _POOL_JOB
    job_seed = _job_seed(spec["seed"], job)
    seed_everything(job_seed)
    env = spec["env_factory"]()
    mind = spec["mind_factory"]()
    try:
        return loop(env, mind, seed=job_seed, **spec["loop_options"])
    finally:
        env.close()


_POOL_LOOP_OPTIONS = ("interpreter", "n_episodes", "max_steps", "policy", "policy_options",
                      "callbacks", "train_mode", "debug_mode", "progress")


def pool(env_factory: Callable, mind_factory: Callable, n_jobs: int, *, workers: int | None = None,
         seed: int = 0, progress: bool = False, **loop_options) -> list[list[dict]]:
    """Run ``n_jobs`` independent :func:`loop` jobs in ``workers`` processes.

    Job ``i`` builds its own environment and mind with the zero-argument factories, after
    seeding Python, NumPy and torch with a seed derived from ``(seed, i)``; the loop gets the
    same seed. The result does not depend on ``workers``: histories come back in job order.
    ``loop_options`` are passed to :func:`loop` (unknown ones raise ``TypeError`` at once).
    ``workers=1`` runs in this process. Worker processes are forked where the platform
    allows it, so factories may be lambdas defined in a notebook.
    """
    unknown = sorted(set(loop_options) - set(_POOL_LOOP_OPTIONS))
    if unknown:
        raise TypeError(f"unknown loop option(s) {unknown}; valid: {', '.join(_POOL_LOOP_OPTIONS)}")
    spec = dict(env_factory=env_factory, mind_factory=mind_factory, seed=seed, loop_options=loop_options)
    workers = workers or min(n_jobs, mp.cpu_count())
    jobs = range(n_jobs)
    if workers == 1:
        _POOL_JOB.update(spec)
        return [_run_job(job) for job in tqdm(jobs, desc="jobs", disable=not progress)]
    method = "fork" if "fork" in mp.get_all_start_methods() else "spawn"
    with mp.get_context(method).Pool(workers, initializer=_init_worker, initargs=(spec,)) as processes:
        results = processes.imap(_run_job, jobs)
        return list(tqdm(results, total=n_jobs, desc="jobs", disable=not progress))
