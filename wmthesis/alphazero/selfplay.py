"""World Models + AlphaZero (thesis 4.3, 5.4.2): tree search inside the deterministic memory.

One real step, top to bottom (:class:`AlphaZeroMind`)::

    frame --vision--> z_t ─┐
    memory state (h_{t-1}, c_{t-1}) ─┴─> root State --MCTS(LatentMDP, Evaluator)--> visit counts N(root, .)
    policy(visit counts) -> a_t;  the memory reads (z_t, a_t) -> (h_t, c_t) for the next root

- :class:`~wmthesis.alphazero.latent_mdp.LatentMDP` wraps a deterministic
  :class:`~wmthesis.world_models.memory.Memory` (thesis 4.3.1) as the
  :class:`~wmthesis.core.MDP` the search expands: a :class:`State` is the latent z,
  the LSTM's (h, c) and a terminal flag; one transition is one LSTM step, whose output h gives
  the next z, the reward and the done flag through the memory's linear heads. Nodes are objects:
  states are never hashed (the author's ``query_tree`` hashed them).
- :class:`~wmthesis.alphazero.heads.AlphaZeroHeads`: linear policy and value heads on ``[z h]``
  (thesis 4.3.3); :class:`~wmthesis.alphazero.heads.Evaluator` hands the search ``(priors, value)``.
- Self-play (:func:`train_alphazero`): games follow the visit counts in proportion for 12
  warm-up steps, then greedily; the latest 1,000 games are kept; after every 10 games, 5 epochs of
  value MSE + policy cross-entropy (to the visit distribution) + L2 1e-4, SGD Nesterov lr 1e-2,
  momentum 0.9, batch 256. Value targets are the discounted returns (:func:`value_targets`).
  A checkpoint (heads, optimiser, counters, curves; the replay's games go to an HDF5 file beside
  it, :mod:`~wmthesis.alphazero.replay`) after every training round lets a
  killed run resume and reach the same heads.

Variants (:data:`~wmthesis.alphazero.variants.VARIANTS`): ``unchanged`` is the thesis's recipe, which "did not train to
properly plan". ``improved`` changes what the diagnosis points at in the search (beyond the
thesis): min-max normalised Q (MuZero: Boxing's rewards are rare and small, so raw Q differences
drown under the prior bonus and the search only follows its priors), equal visit counts broken
by the higher Q (``np.argmax`` gives them to action 0, the no-op), n-step bootstrapped value
targets (lower variance than whole-game returns, no bias at a game cut by ``max_steps``) and no
tree reuse (with concentrated visits a reused tree grows into one ever deeper line, slower at
every step). What it cannot change is the memory: trained on few random rollouts, its reward
head barely predicts held-out rewards (:mod:`~wmthesis.alphazero.diagnosis`). ``learned-reward`` is
improved plus a :class:`RewardModel` for the search's rewards: a class-weighted MLP classifier
on ``[z h a]`` that credits each action with the reward two steps later (when Boxing's punches
land), pretrained on the random rollouts and trained again on them and the self-play games
after every round. It detects the steps before hits far better than chance, but not whose hit
they will be, nor which action makes the difference
(:func:`~wmthesis.alphazero.diagnosis.action_predictability`).
``imitation`` is improved with the heads pretrained, before self-play, on greedy games of an
expert (notebook 02's evolved controller), as AlphaGo's policy started from expert games
(:mod:`wmthesis.alphazero.imitation`): the search then starts from priors that already box.
``own-reward`` is imitation whose search takes its rewards from a reward model
trained on the agent's own games: the memory's reward head learned Boxing from random play,
where the player is mostly hit, and along the imitating agent's fights it predicts the wrong
sign (summed over 10 bouts: -124 against +511), so a deeper search weighs a wrong reward more.
The model predicts the step's own reward (delay 0: a landing punch is already in the frame),
unweighted so that its expectation is calibrated, on the random rollouts and every game in the
replay (the expert's, then self-play's), retrained after imitation and every training round.

Diagnosis (5.4.2 asks "why") and figures: :mod:`wmthesis.alphazero.diagnosis`.
"""
from __future__ import annotations

import dataclasses
import os
import pickle
import time
from pathlib import Path
from typing import Callable

import numpy as np
import torch
from tqdm import tqdm

from wmthesis.alphazero.config import AlphaZeroConfig
from wmthesis.alphazero.heads import AlphaZeroHeads, Evaluator, VALUE_TARGETS, make_optimiser, train_round
from wmthesis.alphazero.imitation import agreement, expert_games
from wmthesis.alphazero.latent_mdp import (LatentMDP, RewardModel, State, reward_fit, reward_rows, rollout_rows,
                                           stack_rows, train_reward_model)
from wmthesis.alphazero.gumbel import root_search
from wmthesis.alphazero.replay import Game, REPLAY_NAME, Replay, game_seeds
from wmthesis.core import Callback, Mind, Proportional, loop
from wmthesis.runs import atomic_path
from wmthesis.training import check_resumable
from wmthesis.utils import check_choice, derive_seeds, fingerprint, read_pickle

FORMAT, FORMAT_VERSION = "wmthesis-alphazero", 2  # 2: the replay in its own HDF5 file
CHECKPOINT_NAME = "alphazero.pkl"
RESUMABLE_FIELDS = ("games", "eval_episodes", "eval_max_steps")  # config fields that may change when resuming


# ----------------------------------------------------------------------------- games


class AlphaZeroMind(Mind, Callback):
    """Vision + memory + MCTS as a HumbleRL mind; also the callback that steps the memory on
    the real action and keeps the search tree, so pass it both ways::

        mind.new_search(seed)
        loop(env, mind, callbacks=[mind], policy="proportional", policy_options={"warmup": 12})

    ``plan(frame)`` encodes the frame, searches from ``State(z, h, c)`` and returns the root
    visit counts (A,). Each finished game is left in :attr:`game` (a :class:`Game`).
    ``vision``: uint8 frames (N, ...) tensor -> latents (N, L) tensor.
    """

    def __init__(self, vision: Callable, mdp: LatentMDP, evaluator: Evaluator, config, keep_frames: bool = False):
        self.vision, self.mdp, self.evaluator, self.config = vision, mdp, evaluator, config
        self.keep_frames = keep_frames
        self.mcts = None
        self.game: Game | None = None
        self.index = 0
        self._root: State | None = None

    def new_search(self, seed: int, index: int = 0) -> None:
        """A fresh search tree with its own noise seed, for game number ``index``."""
        self.mcts = root_search(self.config, self.mdp, self.evaluator, seed)
        self.index = index

    @torch.inference_mode()
    def encode(self, frame) -> np.ndarray:
        """One observation -> z (L,) float32."""
        return self.vision(torch.as_tensor(np.asarray(frame))[None])[0].float().cpu().numpy()

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        if self.mcts is None:
            raise RuntimeError("call new_search(seed) before playing")
        if self._root is not None:
            raise RuntimeError("AlphaZeroMind.plan was called twice without a step: pass the mind "
                               "as a callback too, loop(env, mind, callbacks=[mind])")
        self._root = State(self.encode(state), self.h, self.c)
        counts, info = self.mcts.plan(self._root, train_mode=train_mode, debug_mode=True)
        record = self._steps
        record["features"].append(np.concatenate([self._root.z, self._root.h]))
        if "improved_policy" in info:  # a Gumbel root: the policy it improved, and its own choice
            record["policies"].append(info["improved_policy"])
        else:
            record["policies"].append(counts / counts.sum() if counts.sum() > 0 else np.full(len(counts), 1 / len(counts)))
        record["root_values"].append(info["root_value"])
        record["depths"].append(info["max_depth"])
        record["q"].append(info["q"])
        if self.keep_frames:
            record["frames"].append(np.asarray(state))
        scores = counts
        if "improved_policy" not in info and self.config.tie_break != "first":  # below one visit: counts keep their order
            scores = counts + (tie_breaker(info["q"]) if self.config.tie_break == "q" else 0.5 * info["priors"])
        if not train_mode and self.config.decision_beta is not None:
            scores = prior_and_q(info["priors"], info["q"], info["root_value"], self.config.decision_beta)
        return (scores, info) if debug_mode else scores

    def on_episode_start(self, episode: int, train_mode: bool) -> None:
        self.h = np.zeros(self.mdp.hidden_size, np.float32)
        self.c = np.zeros(self.mdp.hidden_size, np.float32)
        self._root, self._started = None, time.perf_counter()
        self._steps = {key: [] for key in ("features", "policies", "actions", "rewards", "predicted_rewards",
                                           "root_values", "depths", "q", "frames")}
        self._last, self._terminated = None, False
        if self.mcts is not None:
            self.mcts.reset()

    def reset(self) -> None:
        """A fresh episode: zero memory state, an empty tree (the search's seed kept)."""
        self.on_episode_start(self.index, False)

    def observe_step(self, frame, action: int) -> None:
        """One step of an episode seen and taken: ``frame`` encoded, the memory stepped on it and
        ``action`` (no search: the next :meth:`plan` searches from there)."""
        if not hasattr(self, "h"):
            self.reset()
        next_state, _ = self.mdp.transition(State(self.encode(frame), self.h, self.c), int(action))
        self.h, self.c = next_state.h, next_state.c

    def on_step_taken(self, step, transition, info) -> None:
        next_state, predicted = self.mdp.transition(self._root, transition.action)
        self.h, self.c = next_state.h, next_state.c
        for key, value in (("actions", transition.action), ("rewards", transition.reward),
                           ("predicted_rewards", predicted)):
            self._steps[key].append(value)
        self.mcts.advance(transition.action)
        self._root = None
        self._terminated = transition.is_terminal
        if transition.is_terminal or info.get("truncated"):
            self._last = np.concatenate([self.encode(transition.next_state), self.h])

    def on_episode_end(self, episode: int, train_mode: bool) -> None:
        s = self._steps
        self.game = Game(
            index=self.index, features=np.stack(s["features"]).astype(np.float32),
            policies=np.stack(s["policies"]).astype(np.float32), actions=np.array(s["actions"], np.int64),
            rewards=np.array(s["rewards"], np.float32), predicted_rewards=np.array(s["predicted_rewards"], np.float32),
            root_values=np.array(s["root_values"], np.float32), depths=np.array(s["depths"], np.int16),
            q=np.stack(s["q"]).astype(np.float32), terminated=self._terminated,
            last_features=self._last if self._last is not None else s["features"][-1],
            seconds=time.perf_counter() - self._started,
            frames=np.stack(s["frames"]) if s["frames"] else None)

    def on_loop_end(self, is_aborted: bool) -> None:
        self._root = None


def tie_breaker(q: np.ndarray) -> np.ndarray:
    """Added to visit counts so that equal counts go to the higher root Q: the rank of each
    visited action's Q, scaled into [0, 0.5) (below one visit: counts keep their order); 0 for
    unvisited actions (``q`` nan). (A,) -> (A,)."""
    visited = np.isfinite(q)
    ranks = np.argsort(np.argsort(np.where(visited, q, -np.inf)))
    return np.where(visited, 0.5 * ranks / len(q), 0.0)


def prior_and_q(priors: np.ndarray, q: np.ndarray, value: float, beta: float) -> np.ndarray:
    """A greedy game's action scores with ``decision_beta``: ``log P(a) + beta * (Q(a) - V)`` over
    the root's priors P, its Q (nan where unvisited, completed with V, the root's value, as Gumbel
    MuZero completes Q) and ``beta`` per point of return. The search moves the prior's choice by
    its Q differences at a fixed rate, where the most visited action follows argmax Q ever more
    closely as the budget grows. (A,) -> (A,)."""
    completed = np.where(np.isfinite(q), q, value)
    return np.log(np.maximum(np.asarray(priors, np.float64), 1e-12)) + beta * (completed - value)


def play(env, mind: AlphaZeroMind, seed: int, index: int, *, train_mode: bool, max_steps: int | None) -> Game:
    """One game of ``mind`` in ``env`` with the seeds :func:`game_seeds` derives from ``seed``.
    Training games follow the visit counts in proportion for ``warmup`` steps, then greedily;
    test games are greedy."""
    env_seed, search_seed = game_seeds(seed)
    mind.new_search(search_seed, index)
    gumbel = mind.config.root == "gumbel"  # its root's Gumbel noise explores: it acts on the search's choice
    policy = Proportional(warmup=mind.config.warmup) if train_mode and not gumbel else "deterministic"
    loop(env, mind, policy=policy, callbacks=[mind], max_steps=max_steps, seed=env_seed, train_mode=train_mode)
    return mind.game


# ----------------------------------------------------------------------------- training


@dataclasses.dataclass
class AlphaZeroRun:
    """A self-play run (what :func:`train_alphazero` returns and its checkpoint holds).

    ``curve``: per self-play game ``game``, ``return``, ``steps``, ``seconds``; ``tests``: per
    test point ``game``, ``mean``, ``std``, ``returns`` of greedy games; ``rounds``: per
    training round ``game`` and the losses of :func:`train_round`; ``replay``: the latest
    ``replay_games`` :class:`Game` records (a :class:`Replay`); ``task``: sizes and a fingerprint of the memory.
    With ``config["reward_model"]``: the :class:`RewardModel`, its optimiser, and
    ``reward_fits``, per training of it ``game`` (0: on the random rollouts only), ``loss`` and
    its :func:`reward_fit` on the held-out random episodes. With ``config["expert_games"]``:
    ``expert``, the expert games' ``scores`` and ``steps``, and the policy head's ``agreement``
    with the expert's actions before and after pretraining (with the pretraining's losses), and
    ``pretrained``, the heads' weights then (:meth:`pretrained_heads`).
    """

    config: dict
    task: dict
    heads: AlphaZeroHeads
    optimiser: torch.optim.Optimizer
    games: int = 0
    replay: Replay | None = None
    curve: list = dataclasses.field(default_factory=list)
    tests: list = dataclasses.field(default_factory=list)
    rounds: list = dataclasses.field(default_factory=list)
    reward_model: RewardModel | None = None
    reward_optimiser: torch.optim.Optimizer | None = None
    reward_fits: list = dataclasses.field(default_factory=list)
    expert: dict = dataclasses.field(default_factory=dict)
    pretrained: dict | None = None

    def pretrained_heads(self) -> AlphaZeroHeads | None:
        """The heads as they were after imitation, before self-play (None without it)."""
        if self.pretrained is None:
            return None
        heads = AlphaZeroHeads(self.task["latent_size"], self.task["hidden_size"], self.task["n_actions"])
        heads.load_state_dict(self.pretrained)
        return heads

    def summary(self) -> dict:
        """Everything but the replay and the modules, for ``metrics.json``."""
        return {"config": self.config, "task": self.task, "games": self.games, "curve": self.curve,
                "tests": self.tests, "rounds": self.rounds, "reward_fits": self.reward_fits, "expert": self.expert}

    def mdp(self, memory) -> LatentMDP:
        """The model this run searches: the memory, with the run's reward model if it has one."""
        return LatentMDP(memory, self.reward_model)


def train_alphazero(make_env: Callable, vision: Callable, memory, config, *, out_dir: str | os.PathLike | None = None,
                    seed: int = 0, progress: bool = True, rollouts=None,
                    expert: Callable[[int], Mind] | None = None) -> AlphaZeroRun:
    """Self-play training of the heads for ``config.games`` games (the module docstring).

    ``make_env()``: the real game (observations the ``vision`` encodes); ``memory``: a trained
    deterministic memory, frozen. Game ``g`` is seeded from ``(seed, 0, g)``, test ``k`` of a
    test point from ``(seed, 1, k)`` (the same test games each time), training round ``r``
    shuffles with ``(seed, 2, r)``. With ``out_dir``, a checkpoint is written after every
    training round and at the end, and an existing one is resumed (only ``games`` may differ
    from its config; anything else raises :class:`~wmthesis.training.ConfigMismatch`).
    ``config.reward_model``: the search's rewards come from a :class:`RewardModel`, pretrained
    on ``rollouts`` (the random rollouts' :class:`~wmthesis.world_models.train.LatentStore`)
    and trained again on them and the replay after every training round of the heads.
    ``config.expert_games``: before self-play, ``expert(agent_seed)`` (a fresh
    :class:`~wmthesis.core.Mind` per game, e.g. the World Models controller) plays that many
    greedy games of ``config.eval_max_steps`` steps, seeded from ``(seed, 6, k)``; they join
    the replay and the heads train on them for ``config.expert_epochs`` epochs
    (:mod:`wmthesis.alphazero.imitation`).
    """
    check_choice("value target", config.value_target, VALUE_TARGETS)
    if config.reward_model and rollouts is None:
        raise ValueError("reward_model=True needs the random rollouts (rollouts=LatentStore) to pretrain it")
    if config.expert_games < 0 or config.expert_epochs < 0:
        raise ValueError(f"need expert_games and expert_epochs >= 0, got {config.expert_games}, {config.expert_epochs}")
    if config.expert_games and expert is None:
        raise ValueError(f"expert_games={config.expert_games} needs an expert (expert=lambda seed: Mind) to imitate")
    mdp = LatentMDP(memory)
    task = {"latent_size": mdp.latent_size, "hidden_size": mdp.hidden_size, "n_actions": mdp.n_actions,
            "memory": fingerprint(memory)}
    checkpoint = None if out_dir is None else Path(out_dir) / CHECKPOINT_NAME
    run = _resume(checkpoint, config, task) if checkpoint is not None and checkpoint.exists() else None
    if run is None:
        with torch.random.fork_rng():  # the same initial heads for the same seed, whatever ran before
            torch.manual_seed(int(derive_seeds(seed, 5, 0)[0]))
            heads = AlphaZeroHeads(mdp.latent_size, mdp.hidden_size, mdp.n_actions)
        run = AlphaZeroRun(dataclasses.asdict(config), task, heads, make_optimiser(heads, config))
    run.config = dataclasses.asdict(config)
    if run.replay is None:
        run.replay = Replay(config.replay_games)
    if checkpoint is not None:
        run.replay.attach(checkpoint.with_name(REPLAY_NAME))
    rows = rollout_rows(mdp, rollouts, config.reward_delay) if config.reward_model else None
    if config.reward_model and run.reward_model is None:
        with torch.random.fork_rng():
            torch.manual_seed(int(derive_seeds(seed, 4, 0)[0]))
            run.reward_model = RewardModel(mdp.latent_size + mdp.hidden_size, mdp.n_actions, config.reward_hidden,
                                           config.reward_range)
        run.reward_optimiser = make_reward_optimiser(run.reward_model, config)
        _train_reward(run, rows, config, config.reward_pretrain_epochs, seed)
    mdp = run.mdp(memory)
    mind = AlphaZeroMind(vision, mdp, Evaluator(run.heads), config)
    env = make_env()
    try:
        if config.expert_games and not run.expert:
            _imitate(run, env, expert, vision, mdp, config, seed, progress)
            if config.reward_model:  # the expert's games are the agent's first own games
                _train_reward(run, rows, config, config.reward_epochs, seed)
            if checkpoint is not None:
                save_run(run, checkpoint)
        with tqdm(total=config.games, initial=run.games, desc="self-play", disable=not progress) as bar:
            while run.games < config.games:
                g = run.games
                game = play(env, mind, int(derive_seeds(seed, 0, g)[0]), g, train_mode=True,
                            max_steps=config.max_steps)
                run.replay.append(game)
                run.curve.append({"game": g + 1, "return": game.score, "steps": len(game), "seconds": game.seconds})
                run.games = g + 1
                trained = run.games % config.train_every == 0
                if trained:
                    rng = np.random.default_rng(derive_seeds(seed, 2, run.games // config.train_every))
                    run.rounds.append({"game": run.games, **train_round(run.heads, run.optimiser, run.replay,
                                                                         config, rng)})
                    if config.reward_model:
                        _train_reward(run, rows, config, config.reward_epochs, seed)
                if config.test_every and run.games % config.test_every == 0:
                    tests = [play(env, mind, int(derive_seeds(seed, 1, k)[0]), k, train_mode=False,
                                  max_steps=config.max_steps) for k in range(config.test_episodes)]
                    returns = [test.score for test in tests]
                    run.tests.append({"game": run.games, "mean": float(np.mean(returns)), "std": float(np.std(returns)),
                                      "returns": returns, "steps": int(sum(len(test) for test in tests))})
                if checkpoint is not None and (trained or run.games == config.games):
                    save_run(run, checkpoint)
                bar.update(1)
                bar.set_postfix(score=f"{game.score:.0f}")
    finally:
        env.close()
        run.replay.close()
    return run


def _imitate(run: AlphaZeroRun, env, expert: Callable, vision: Callable, mdp: LatentMDP, config, seed: int,
             progress: bool) -> None:
    """Play ``config.expert_games`` expert games into the replay and pretrain the heads on them;
    ``run.expert`` keeps their scores and the heads' agreement with the expert's actions."""
    seeds = [int(derive_seeds(seed, 6, k)[0]) for k in range(config.expert_games)]
    games = expert_games(env, expert, vision, mdp, seeds, max_steps=config.eval_max_steps, progress=progress)
    run.replay.extend(games)
    before = agreement(run.heads, games)
    rng = np.random.default_rng(derive_seeds(seed, 2, 0))
    losses = train_round(run.heads, run.optimiser, games, dataclasses.replace(config, epochs=config.expert_epochs), rng)
    run.expert = {"games": len(games), "scores": [g.score for g in games], "steps": int(sum(map(len, games))),
                  "agreement_before": before, "agreement": agreement(run.heads, games), **losses}
    run.pretrained = {k: v.clone() for k, v in run.heads.state_dict().items()}


def make_reward_optimiser(model: RewardModel, config) -> torch.optim.Optimizer:
    """Adam for the reward model (weight decay 1e-4 against fitting 20 bouts' hits by heart)."""
    return torch.optim.Adam(model.parameters(), lr=config.reward_lr, weight_decay=1e-4)


def _train_reward(run: AlphaZeroRun, rows: dict, config, epochs: int, seed: int) -> None:
    """Train the run's reward model on the random rollouts' training episodes and every step of
    the replay (self-play data: the states and actions the search actually visits), then
    record its fit on the held-out random episodes in ``run.reward_fits``."""
    games = [reward_rows(g.features, g.actions, g.rewards, config.reward_delay) for g in run.replay]
    data = stack_rows([rows["train"], *games])
    rng = np.random.default_rng(derive_seeds(seed, 4, len(run.reward_fits) + 1))
    loss = train_reward_model(run.reward_model, run.reward_optimiser, data, epochs, config.batch_size, rng,
                              config.reward_weighted)
    run.reward_fits.append({"game": run.games, "loss": loss, **reward_fit(run.reward_model, rows["val"])})


def _resume(path: Path, config, task: dict) -> AlphaZeroRun:
    run = load_run(path)
    check_resumable(path, (run.config, run.task), (dataclasses.asdict(config), task), RESUMABLE_FIELDS)
    return run


def save_run(run: AlphaZeroRun, path: str | os.PathLike) -> None:
    """Write the run (heads, optimiser, counters, curves, and the serials of the replay's games,
    which its HDF5 file holds) atomically; then the replay lets go of the games it no longer names."""
    replay = {"serials": list(run.replay.serials), "next_serial": run.replay.next_serial}
    saved = {"format": FORMAT, "version": FORMAT_VERSION, **run.summary(), "replay": replay,
             "heads": run.heads.state_dict(), "optimiser": run.optimiser.state_dict()}
    if run.pretrained is not None:
        saved["pretrained"] = run.pretrained
    if run.reward_model is not None:
        saved["reward_model"] = run.reward_model.state_dict()
        saved["reward_optimiser"] = run.reward_optimiser.state_dict()
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        pickle.dump(saved, f, protocol=pickle.HIGHEST_PROTOCOL)
    run.replay.prune()


def load_run(path: str | os.PathLike) -> AlphaZeroRun:
    """An :class:`AlphaZeroRun` from its checkpoint (or the folder holding it) and the replay
    file beside it. A checkpoint of version 1 (its replay pickled inside) is read too; the run's
    next checkpoint moves that replay to the HDF5 file."""
    path = Path(path)
    path = path / CHECKPOINT_NAME if path.is_dir() else path
    saved = read_pickle(path)
    if not isinstance(saved, dict) or saved.get("format") != FORMAT or saved.get("version") not in (1, FORMAT_VERSION):
        raise ValueError(f"{path} is not a {FORMAT} checkpoint of version {FORMAT_VERSION}")
    # fields added to AlphaZeroConfig later take their defaults, which keep the older behaviour
    saved["config"] = {**dataclasses.asdict(AlphaZeroConfig()), **saved["config"]}
    t = saved["task"]
    heads = AlphaZeroHeads(t["latent_size"], t["hidden_size"], t["n_actions"])
    heads.load_state_dict(saved["heads"])
    config = AlphaZeroConfig(**saved["config"])
    optimiser = make_optimiser(heads, config)
    optimiser.load_state_dict(saved["optimiser"])
    if saved["version"] == 1:
        replay = Replay(config.replay_games, saved["replay"], range(len(saved["replay"])), len(saved["replay"]))
    else:
        replay = Replay.load(path.with_name(REPLAY_NAME), config.replay_games, **saved["replay"])
    run = AlphaZeroRun(saved["config"], t, heads, optimiser, saved["games"], replay,
                       saved["curve"], saved["tests"], saved["rounds"], reward_fits=saved.get("reward_fits", []),
                       expert=saved.get("expert", {}), pretrained=saved.get("pretrained"))
    if "reward_model" in saved:
        run.reward_model = RewardModel(t["latent_size"] + t["hidden_size"], t["n_actions"], config.reward_hidden,
                                       config.reward_range)
        run.reward_model.load_state_dict(saved["reward_model"])
        run.reward_optimiser = make_reward_optimiser(run.reward_model, config)
        run.reward_optimiser.load_state_dict(saved["reward_optimiser"])
    return run
