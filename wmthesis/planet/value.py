"""A short-horizon action value on a trained RSSM's latent (beyond the thesis).

CEM's imagined returns need the reward model to tell which action lands a reward. In Boxing
a punch thrown at step t scores at t + 2, and a model trained on 32x32 frames ranks the action
that landed a hit barely above the others (session 13's measurements in issue 13). This module
keeps the trained RSSM frozen and learns, on its features, the reward that an action brings
over the next few steps:

    Q(h_t, s_t, a) = value(h_{t+1}, mean of p(s_{t+1} | h_{t+1})),   h_{t+1} = f(h_t, s_t, a)
    target: r_t + r_{t+1} + ... + r_{t+n-1}   (n = ``reward_steps``, within the episode)

(or each reward discounted, ``gamma^k r_{t+k}``: the ``discounted-sum`` target, for games whose
rewards lie far apart, such as Freeway's crossings; its logarithm, ``log-discounted-sum``, fitted
as ``log(sum + gamma^n)`` so that a step nearer a far reward weighs as much as one near it: one
step is a factor of 1/gamma on any scale; or temporal differences, ``td``)

where ``r_t`` is the reward of taking ``a_t``. The features are the one-step prior of the
planner's first imagined step, so the action enters through the RSSM's own transition. The
agent (:class:`ValueMind`) filters ``(h_t, s_t)`` with the posterior mean and takes the argmax
of Q over all actions: one transition per action, no CEM. It learns like a fitted-Q iteration
on its own play: the value is fitted on random bouts, then each round adds ``bouts_per_round``
epsilon-greedy bouts of the value agent to its store and refits on all of it. Fitted Q swings
from round to round (its own bouts change its data), so the agent is the round whose value
scored best on greedy validation bouts of their own; Q is the mean of an ensemble of heads.
"""
from __future__ import annotations

import dataclasses
from contextlib import contextmanager, nullcontext
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn
from tqdm import tqdm

from wmthesis.config import LatentValueConfig
from wmthesis.core import loop
from wmthesis.data import EpisodeBuffer, EpisodeStore, play_random_episode
from wmthesis.envs.preprocessing import to_float
from wmthesis.planet.rssm import RSSM, one_hot_previous
from wmthesis.planet.train import BeliefFilter
from wmthesis.training import gradient_step, with_added_defaults
from wmthesis.utils import check_choice, derive_seeds, fingerprint, parallel_calls, process_pool
from wmthesis.runs import atomic_path

STORE, CHECKPOINT = "episodes.h5", "value.pt"
TARGETS = ("reward-sum", "discounted-sum", "log-discounted-sum", "td")


def reward_sums(rewards: np.ndarray, steps: int, discount: float = 1.0) -> np.ndarray:
    """(T,) -> (T,): ``r_t + discount r_{t+1} + ... + discount^(steps-1) r_{t+steps-1}`` of one
    episode, cut at its end."""
    if steps < 1:
        raise ValueError(f"reward_steps must be >= 1, got {steps}")
    padded = np.concatenate([np.asarray(rewards, np.float32), np.zeros(steps - 1, np.float32)])
    weights = (discount ** np.arange(steps)).astype(np.float32)
    return np.correlate(padded, weights, mode="valid")


def td_targets(sums: torch.Tensor, values: torch.Tensor, steps: int, discount: float) -> torch.Tensor:
    """One episode's temporal-difference targets (T,): ``sums[t] + discount^steps values[t + steps]``,
    with nothing after the episode's end (``values`` (T,): max_a Q of each step's belief)."""
    boot = torch.zeros_like(sums)
    boot[:max(len(sums) - steps, 0)] = values[steps:]
    return sums + discount ** steps * boot


@torch.inference_mode()
def best_values(model: RSSM, value: nn.Module, beliefs: torch.Tensor, states: torch.Tensor,
                chunk: int = 4096) -> torch.Tensor:
    """``max_a Q(h, s, a)`` (T,) of beliefs (T, H) and states (T, S), every action through the
    model's transition (:func:`after_action`), ``chunk`` beliefs at a time."""
    return torch.cat([action_values(model, value, beliefs[start:start + chunk], states[start:start + chunk]).amax(-1)
                      for start in range(0, len(beliefs), chunk)])


def action_values(model: RSSM, value: nn.Module, beliefs: torch.Tensor, states: torch.Tensor) -> torch.Tensor:
    """Q of every action (T, A) from beliefs (T, H) and states (T, S), each action through the
    model's transition (:func:`after_action`)."""
    count = model.n_actions
    every = torch.arange(count, device=beliefs.device)
    features = after_action(model, beliefs.repeat_interleave(count, 0), states.repeat_interleave(count, 0),
                            every.repeat(len(beliefs)))
    return value(features).reshape(len(beliefs), count)


def after_action(model: RSSM, belief: torch.Tensor, state: torch.Tensor, actions: torch.Tensor) -> torch.Tensor:
    """Features of taking ``actions`` (...,) long from ``(h_t, s_t)``, (..., H) and (..., S):
    ``(h_{t+1}, mean of p(s_{t+1} | h_{t+1}))``, (..., H + S)."""
    belief, prior = model.transition(belief, state, F.one_hot(actions, model.n_actions).float())
    return torch.cat([belief, prior.mean], -1)


class LatentValue(nn.Module):
    """An ensemble of ``heads`` two-layer heads of width ``hidden``: features (..., F) -> Q (...,),
    the mean of the heads (:meth:`each` gives them apart, (..., heads)). With ``log``, the heads
    fit the logarithm of Q (the ``log-discounted-sum`` target) and Q is the exponential of their
    mean, on the scale of rewards."""

    def __init__(self, features: int, hidden: int, heads: int = 1, log: bool = False):
        super().__init__()
        if heads < 1:
            raise ValueError(f"heads must be >= 1, got {heads}")
        self.heads = nn.ModuleList(nn.Sequential(nn.Linear(features, hidden), nn.ReLU(), nn.Linear(hidden, hidden),
                                                 nn.ReLU(), nn.Linear(hidden, 1)) for _ in range(heads))
        self.log = log

    def each(self, features: torch.Tensor) -> torch.Tensor:
        return torch.cat([head(features) for head in self.heads], -1)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        q = self.each(features).mean(-1)
        return q.exp() if self.log else q


def log_scaled(config: LatentValueConfig | dict) -> bool:
    """Whether a value of ``config`` (or its saved dict) fits the logarithm of its target."""
    target = config.get("target") if isinstance(config, dict) else config.target
    return target == "log-discounted-sum"


@torch.inference_mode()
def episode_features(model: RSSM, episode: dict[str, np.ndarray], bits: int, seed: int,
                     beliefs: bool = False):
    """Features of each taken action of a stored episode (observations (T, H, W, 3) uint8,
    actions (T,)), filtering with the posterior as in training: (T, H + S); with ``beliefs``,
    also each step's belief (T, H) and posterior mean (T, S) before its action."""
    generator = torch.Generator(next(model.parameters()).device).manual_seed(seed)
    frames = to_float(torch.as_tensor(episode["observations"], device=generator.device)[None], bits, noise=generator)
    actions = torch.as_tensor(episode["actions"], device=generator.device)
    trajectory = model.observe(model.encode(frames), one_hot_previous(actions[None], model.n_actions), generator)
    h, s = trajectory.beliefs[0], trajectory.posterior.mean[0]
    features = after_action(model, h, s, actions)
    return (features, h, s) if beliefs else features


class ValueMind(BeliefFilter):
    """The value agent for :func:`~wmthesis.core.loop`, passed as the mind and among the
    callbacks (:class:`~wmthesis.planet.train.BeliefFilter`). :meth:`plan` filters
    ``(h_t, s_t)`` with the frame (the posterior's mean) and returns Q of every action."""

    def __init__(self, model: RSSM, value: LatentValue, bits: int = 5, seed: int = 0):
        super().__init__(model, bits, torch.Generator(next(model.parameters()).device).manual_seed(int(seed)))
        self.value = value

    @torch.inference_mode()
    def plan(self, frame: np.ndarray, train_mode: bool = True, debug_mode: bool = False) -> np.ndarray:
        self.observe(frame, sample=False)
        return action_values(self.model, self.value, self.belief, self.state)[0].cpu().numpy()


def fit_value(value: LatentValue, features: torch.Tensor, targets: torch.Tensor,
              config: LatentValueConfig, seed: int) -> float:
    """``config.fit_updates`` Adam steps of mean squared error on (features (N, F), targets (N,)),
    each head on its own random batches, through the shared guarded step (a NaN stops the fit
    with :class:`~wmthesis.training.NonFiniteLoss` before that update); returns the last step's
    loss, averaged over the heads."""
    optimizer = torch.optim.Adam(value.parameters(), lr=config.lr)
    rng = np.random.default_rng(seed)
    loss = torch.zeros(())
    for update in range(1, config.fit_updates + 1):
        batches = torch.as_tensor(rng.integers(len(targets), size=(len(value.heads), config.batch_size)),
                                  device=targets.device)
        loss = sum(F.mse_loss(head(features[batch]).squeeze(-1), targets[batch])
                   for head, batch in zip(value.heads, batches)) / len(value.heads)
        gradient_step("latent value", update, {"loss": loss}, optimizer, value.parameters(),
                      kept="the value of the last finished round is kept in value.pt")
    return float(loss.detach())


def _dataset(model: RSSM, path: Path, config: LatentValueConfig, bits: int, cache: list[dict]) -> list[dict]:
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


def play_value(env, model: RSSM, value: LatentValue, bits: int, env_seed: int, mind_seed: int,
               epsilon: float = 0.0) -> dict[str, np.ndarray]:
    """One episode of the value agent, greedy (``epsilon`` 0) or epsilon-greedy: the arrays of
    :meth:`~wmthesis.data.EpisodeStore.append_episode`."""
    mind, record = ValueMind(model, value, bits, mind_seed), EpisodeBuffer()
    policy = "epsilon-greedy" if epsilon else "deterministic"
    loop(env, mind, policy=policy, policy_options={"epsilon": epsilon} if epsilon else None,
         callbacks=[mind, record], seed=int(env_seed), train_mode=False)
    return record.episode


def _play_made(make_env: tuple, model: RSSM, value: LatentValue, bits: int, env_seed: int, mind_seed: int,
               epsilon: float) -> dict[str, np.ndarray]:
    """:func:`play_value` in an environment of its own, ``make_env`` = ``(fn, *args)``."""
    fn, *args = make_env
    env = fn(*args)
    try:
        return play_value(env, model, value, bits, env_seed, mind_seed, epsilon)
    finally:
        env.close()


def play_values(env, model: RSSM, value: LatentValue, bits: int, seeds, epsilon: float = 0.0,
                pool: tuple | None = None, on_done=None) -> list[dict[str, np.ndarray]]:
    """:func:`play_value` on each (environment, mind) pair of ``seeds``, in order. With ``pool``
    (``(executor, make_env)``, :func:`bout_pool`), in its processes, two bouts at a time: the
    same bouts, each seeded by its pair. ``on_done(index, episode)`` is called in the order of
    ``seeds``, as soon as each bout and those before it have ended (to store them in order)."""
    seeds = [tuple(int(v) for v in pair) for pair in seeds]
    on_done = on_done or (lambda index, episode: None)
    if pool is None:
        episodes = []
        for index, pair in enumerate(seeds):
            episodes.append(play_value(env, model, value, bits, *pair, epsilon))
            on_done(index, episodes[-1])
        return episodes
    executor, make_env = pool
    ended, given = {}, [0]

    def in_order(index: int, episode: dict) -> None:
        ended[index] = episode
        while given[0] in ended:
            on_done(given[0], ended.pop(given[0]))
            given[0] += 1

    calls = [(_play_made, make_env, model, value, bits, *pair, epsilon) for pair in seeds]
    return parallel_calls(calls, progress=False, on_done=in_order, executor=executor)


@contextmanager
def bout_pool(model: RSSM, make_env: tuple | None):
    """The ``pool`` of :func:`play_values` for a run: processes of their own (:func:`~wmthesis.utils.process_pool`)
    that build the game with ``make_env`` (``(fn, *args)``, module-level); None (bouts in this
    process) without ``make_env``, on one core, or for a model on a GPU."""
    on_cpu = next(model.parameters()).device.type == "cpu"
    with process_pool() if make_env is not None and on_cpu else nullcontext(None) as executor:
        yield None if executor is None else (executor, make_env)


def evaluation_seeds(seed: int, k: int) -> tuple[int, int]:
    """The (environment, mind) seeds of greedy test bout ``k``: those of the PlaNet agent's
    evaluation bouts (:func:`~wmthesis.experiments.planet_boxing.planet_boxing_agent`)."""
    env_seed, mind_seed = derive_seeds(seed, 3, k, n=2)
    return int(env_seed), int(mind_seed)


def validation_seeds(seed: int, k: int) -> tuple[int, int]:
    """The (environment, mind) seeds of greedy validation bout ``k``, apart from the test bouts
    and from the bouts it learns on: the bouts that choose among the rounds' values."""
    env_seed, mind_seed = derive_seeds(seed, 6, k, n=2)
    return int(env_seed), int(mind_seed)


def _greedy_returns(env, model: RSSM, value: LatentValue, bits: int, seeds, first_steps: int = 0,
                    pool: tuple | None = None):
    """The greedy bouts' returns (:func:`play_values`); with ``first_steps``, also the returns of
    their first steps."""
    rewards = [episode["rewards"] for episode in play_values(env, model, value, bits, seeds, pool=pool)]
    full = [float(r.sum()) for r in rewards]
    return (full, [float(r[:first_steps].sum()) for r in rewards]) if first_steps else full


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
    and ``run_dir``. Every round's value is kept (``rounds`` in the checkpoint). Without
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
            episodes = _store_bouts(run_dir / STORE, env, model, value, bits, config, seed, round_, pool)
            data = _dataset(model, run_dir / STORE, config, bits, cache)
            loss = _fit_round(value, model, data, config, int(derive_seeds(seed, 5, round_)[0]), fitted=round_ > 0)
            scores = _scores(env, model, value, bits, config, seed, first_steps, pool) if config.score_rounds else {}
            curve.append({"round": round_, "episodes": episodes, **scores, "loss": loss})
            rounds = state.setdefault("rounds", {})
            rounds[round_] = {key: v.clone() for key, v in value.state_dict().items()}
            if config.score_rounds and best_round(curve) == round_:
                state["best"] = rounds[round_]
            with atomic_path(saved) as tmp:
                torch.save({"value": value.state_dict(), **({"best": state["best"]} if "best" in state else {}),
                            "rounds": rounds, "curve": curve, "config": dataclasses.asdict(config),
                            "model": fingerprint(model)}, tmp)
        agent = _agent(env, model, bits, config, run_dir, seed=seed, progress=progress, first_steps=first_steps,
                       pool=pool)
    return {"curve": curve, "best_round": best_round(curve) if config.score_rounds else None, "agent": agent,
            "run_dir": str(run_dir)}


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
    ``first_returns`` (their first ``first_steps`` steps), ``mean`` and ``std``."""
    chosen = {}
    if validation:
        returns = _greedy_returns(env, model, value, bits, [validation_seeds(seed, k) for k in range(config.validation_bouts)],
                                  pool=pool)
        chosen = {"validation": returns, "validation_mean": float(np.mean(returns))}
    returns, first = _greedy_returns(env, model, value, bits, [evaluation_seeds(seed, k) for k in range(config.test_bouts)],
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
    value, data = _first_value(model, config, seed), _dataset(model, path.parent / STORE, config, bits, [])
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


def round_ensemble(states: list[dict], hidden: int, log: bool = False) -> LatentValue:
    """One value whose heads are those of several rounds' values (state dicts of
    :class:`LatentValue`, the same number of heads each): Q is the mean over the rounds (a
    snapshot ensemble, which averages out fitted Q's swings from round to round; with ``log``,
    the values' logarithms are averaged)."""
    if not states:
        raise ValueError("round_ensemble needs at least one round's value")
    heads = 1 + max(int(key.split(".")[1]) for key in states[0])
    features = states[0]["heads.0.0.weight"].shape[1]
    value = LatentValue(features, hidden, heads * len(states), log).to(states[0]["heads.0.0.weight"].device)
    value.load_state_dict({f"heads.{i * heads + int(key.split('.')[1])}.{key.split('.', 2)[2]}": tensor
                           for i, state in enumerate(states) for key, tensor in state.items()})
    return value.eval()


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


def load_rounds(run_dir, model: RSSM, rounds: list[int]) -> LatentValue:
    """The mean of the values of ``rounds`` of a :func:`train_value` run for ``model``
    (:func:`round_ensemble`; the rounds kept, :func:`round_values`)."""
    path = Path(run_dir) / CHECKPOINT
    return _kept_mean(_load_checked(path, model), rounds, path)


def load_value(run_dir, model: RSSM) -> LatentValue:
    """The agent of a :func:`train_value` run for ``model``: its chosen round's value
    (:func:`best_round`), or the mean of the rounds' values that made its agent (``agent_rounds``)."""
    path = Path(run_dir) / CHECKPOINT
    state = _load_checked(path, model)
    chosen = state.get("agent", {}).get("rounds", [])
    if chosen and ("best" not in state or chosen != [best_round(state["curve"])]):
        return _kept_mean(state, chosen, path)
    if "best" not in state:
        raise ValueError(f"{path} was fitted before values were chosen on validation bouts; "
                         "run train_value again in a new folder")
    config = LatentValueConfig(**with_added_defaults(LatentValueConfig, state["config"]))
    value = LatentValue(model.belief_size + model.state_size, config.hidden_size, config.heads,
                        log_scaled(config)).to(next(model.parameters()).device)
    value.load_state_dict(state["best"])
    return value.eval()


__all__ = ["LatentValue", "ValueMind", "after_action", "episode_features", "fit_value", "load_value", "play_value",
           "reward_sums", "log_scaled", "td_targets", "best_values", "action_values", "TARGETS", "evaluation_seeds", "validation_seeds", "best_round", "train_value",
           "round_values", "round_ensemble", "agent_rounds", "load_rounds", "play_values", "bout_pool"]
