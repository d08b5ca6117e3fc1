"""A trained agent, one way for every family: ``wmthesis.load(experiment, variant=None, profile="quick", seed=0)``.

    agent = wmthesis.load("boxing-wm")           # the shipped quick seed-0 agent
    env = agent.env()                            # the game as it was trained and scored on
    agent.play(bouts=1)                          # the scored bouts, as the evaluation played them: [44.0]
    agent.play(bouts=1, policy=lambda frame: 0, max_steps=300)   # a policy of one's own, same env
    agent.mind()                                 # a mind for wmthesis.core.loop
    agent.vision, agent.memory, agent.controller # its parts by their thesis names

Every agent has ``env()``, ``mind()``, ``play()``, ``experiment``, ``variant``, ``profile``,
``seed``, ``path`` and ``info`` (what its file says of it), and the parts its family has:
``vision``, ``memory``, ``controller`` (World Models), ``search`` (the tree search of World Models
+ AlphaZero, the best-first search of Sokoban), ``model``, ``planner`` and ``value`` (PlaNet and
its value; Sokoban's learned model and value). A part the family lacks is None.

This module loads no torch until an agent is loaded: a bad name is refused at once.
"""
from __future__ import annotations

from pathlib import Path
from typing import Callable

import numpy as np

from wmthesis.config import PROFILES
from wmthesis.declarations import AGENTS, DECLARED, resolve
from wmthesis.utils import check_bouts, check_choice


def agent_file(experiment: str, variant: str | None = None, profile: str = "quick", seed: int = 0) -> Path:
    """The file of ``experiment``'s trained agent (``variant``: one of its variants, None its
    default) for ``profile`` and ``seed``; ValueError naming the valid choices otherwise."""
    from wmthesis.utils import data_dir

    check_choice("experiment with an agent", experiment, AGENTS)
    check_choice("profile", profile, PROFILES)
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2**31:
        raise ValueError(f"seed must be an integer in [0, 2**31), got {seed!r}")
    declaration = DECLARED[experiment]
    registry = declaration.registry()
    if registry is None:
        if variant is not None:
            raise ValueError(f"{experiment} has no variants, got {variant!r}")
        name = folder = None
    else:
        name, folder = registry.check(variant).name, registry.folder_name(variant)
    return data_dir() / declaration.agent.path(profile, seed, name, folder)


def load(experiment: str, *, variant: str | None = None, profile: str = "quick", seed: int = 0):
    """The trained agent of ``experiment`` (see the module docstring): the one trained in the data
    folder, else the one the repository ships (whatever ``$WMTHESIS_DATA`` says). Nothing is
    trained or downloaded: an agent that is not there raises FileNotFoundError naming the command
    that trains it; a file that is truncated, of another experiment or of an older format raises
    ValueError naming the file."""
    from wmthesis.utils import data_dir, shipped_dir

    path = agent_file(experiment, variant, profile, seed)
    shipped = None if shipped_dir() is None else shipped_dir() / path.relative_to(data_dir())
    if not path.is_file() and shipped is not None and shipped.is_file():
        path = shipped
    if not path.is_file():
        flag = f" --variant {variant}" if variant else ""
        raise FileNotFoundError(f"no trained {experiment} agent at {path}: train it with `python -m wmthesis "
                                f"reproduce {experiment} --profile {profile} --seed {seed}{flag}`")
    declaration = DECLARED[experiment]
    registry = declaration.registry()
    name = None if registry is None else registry.check(variant).name
    agent = resolve(declaration.agent.loader)(path, experiment=experiment, variant=name, profile=profile, seed=seed)
    if agent.game != declaration.agent.game:
        raise ValueError(f"{path} holds a {agent.game} agent, not {experiment}'s ({declaration.agent.game})")
    if agent.says_variant not in (None, name):
        raise ValueError(f"{path} holds {experiment}'s {agent.says_variant} agent, not {name}")
    return agent


class TrainedAgent:
    """What every loaded agent has (the module docstring); a family fills in :meth:`env`,
    :meth:`mind`, :meth:`scored_seeds` and :meth:`play_scored`."""
    vision = memory = controller = search = model = planner = value = None
    game: str = ""  # the game its file says it plays
    says_variant: str | None = None  # the variant its file says it is (None: the file does not say)

    def __init__(self, path: Path, experiment: str, variant: str | None, profile: str, seed: int, info: dict):
        self.path, self.experiment, self.variant, self.profile, self.seed = Path(path), experiment, variant, profile, seed
        self.info = info

    def __repr__(self) -> str:
        parts = [p for p in ("vision", "memory", "controller", "search", "model", "planner", "value")
                 if getattr(self, p) is not None]
        return (f"<{type(self).__name__} {self.experiment}{':' + self.variant if self.variant else ''} "
                f"{self.profile} seed {self.seed}: {', '.join(parts)}>")

    def env(self):
        """The environment the agent was trained and scored on, with the same preprocessing."""
        raise NotImplementedError

    def mind(self):
        """A mind that :func:`wmthesis.core.loop` plays (pass it as a callback too)."""
        raise NotImplementedError

    def scored_seeds(self, bouts: int) -> list[int]:
        """The reset seeds of the first ``bouts`` scored bouts (or levels)."""
        raise NotImplementedError

    def play_bouts(self, bouts: int, frames: list | None = None, on_bout: Callable | None = None) -> list[dict]:
        """The first ``bouts`` scored bouts (or levels), played as the evaluation played them: one
        dict each (``bout``, ``return``, ``steps``, and what the family adds), ``on_bout(play)``
        called as each ends; ``frames`` (a list) gets each bout's frames, (T + 1, H, W, 3) uint8."""
        raise NotImplementedError

    def play_scored(self, bouts: int) -> list[float]:
        """The agent's returns on its first ``bouts`` scored bouts, played as its evaluation did."""
        return [p["return"] for p in self.play_bouts(bouts)]

    video_scale, fps = 4, 15  # how `play --video` shows its frames

    def bout_line(self, play: dict) -> str:
        """One line for a bout :meth:`play_bouts` played."""
        return f"bout {play['bout']}: {play['return']:+.0f} in {play['steps']} steps"

    def score_line(self, plays: list[dict]) -> str:
        """The closing line over the bouts played."""
        mean = sum(p["return"] for p in plays) / len(plays)
        return (f"mean {mean:.1f} over {len(plays)} bout{'s' if len(plays) > 1 else ''} "
                f"({self.variant or self.experiment}, {self.profile}, seed {self.seed})")

    # ---------------------------------------------------------------- what it thinks
    horizon = 8  # how many steps ahead a recording shows the agent's imagination
    shown = (1, 4, 8)  # the steps ahead whose imagined frames a recording decodes (where decoding is costly)
    max_steps: int | None = None  # the step limit its scored bouts were played with

    @property
    def scored_bouts(self) -> int | None:
        """How many scored bouts its file holds (None: its bouts are drawn afresh, as many as asked)."""
        return None

    def scored_minds(self, bouts: int) -> list[tuple[int, object]]:
        """``(reset seed, mind)`` of each of the first ``bouts`` scored bouts, the mind seeded as
        the evaluation seeded it."""
        return [(seed, self.mind()) for seed in self.scored_seeds(bouts)]

    def thought(self, mind):
        """What ``mind`` thought once it planned (a :class:`~wmthesis.thoughts.Thought`)."""
        raise NotImplementedError

    def snapshot(self, mind):
        """What a recording keeps of ``mind`` once it planned, for :meth:`thoughts` (by default the
        :meth:`thought` itself)."""
        return self.thought(mind)

    def thoughts(self, snapshots: list) -> list:
        """The :class:`~wmthesis.thoughts.Thought` of each snapshot, in order."""
        return snapshots

    decoded: str | None = None  # what a recording decodes into frames (None: nothing)
    fit_decoder: str = ""  # the command that fits a decoder where none ships
    decoder_info: dict | None = None  # the shipped decoder's ``fitted_on`` (None: none ships)

    def left_out(self) -> str | None:
        """Which panels a recording leaves out and why (a missing decoder), or None."""
        if self.decoded is None or self.decoder_info is not None:
            return None
        return f"left out: {self.decoded} (no decoder ships with this agent; `{self.fit_decoder}` fits one)"

    def record(self, bouts: int, path, video=None, on_bout: Callable | None = None) -> dict:
        """The first ``bouts`` scored bouts played as the evaluation played them, each step's frame
        beside what the agent thought (:mod:`wmthesis.thoughts`) in a rerun recording at ``path``
        (and an mp4 of its panels at ``video``): ``plays`` (one dict each, ``on_bout(play)`` as each
        ends), ``steps`` recorded and ``errors``, imagination's mean error per imagined step. A bout
        cut off (Ctrl-C) leaves a recording that opens."""
        from wmthesis.thoughts import Recorder

        recorder = Recorder(path, horizon=self.horizon, video=video, scale=self.video_scale, fps=self.fps,
                            left_out=self.left_out())
        plays: list[dict] = []
        try:
            self.record_bouts(bouts, recorder, plays, on_bout)
        finally:
            summary = recorder.close()
        return {"plays": plays, **summary}

    def record_bouts(self, bouts: int, recorder, plays: list, on_bout: Callable | None = None) -> None:
        """Play the scored bouts through :meth:`env` with :meth:`scored_minds`, one
        :func:`wmthesis.core.loop` each, the recorder watching; ``plays`` gets each play."""
        from wmthesis.core import loop
        from wmthesis.thoughts import Watcher

        env, watcher = self.env(), None
        try:
            for k, (seed, mind) in enumerate(self.scored_minds(bouts)):
                watcher = Watcher(recorder, lambda mind=mind: self.snapshot(mind), self.thoughts)
                watcher.bout = k
                history = loop(env, mind, policy="deterministic", callbacks=[mind, watcher], seed=int(seed),
                               max_steps=self.max_steps, train_mode=False)
                plays.append({"bout": k, "return": float(history[0]["return"]), "steps": int(history[0]["steps"])})
                if on_bout is not None:
                    on_bout(plays[-1])
        finally:
            if watcher is not None:
                watcher.flush()  # an interrupted bout keeps what it played
            env.close()

    def stretch(self, bout: int = 0, steps: int = 100):
        """The first ``steps`` steps of scored bout ``bout`` as the agent played them: the frames it
        saw (steps, ...) uint8 and the action it took at each (steps,)."""
        from wmthesis.core import loop
        from wmthesis.rollouts import EpisodeBuffer

        seed, mind = self.scored_minds(bout + 1)[bout]
        env, kept = self.env(), EpisodeBuffer()
        try:
            loop(env, mind, policy="deterministic", callbacks=[mind, kept], seed=int(seed), max_steps=steps,
                 train_mode=False)
        finally:
            env.close()
        return kept.episode["observations"][:steps], kept.episode["actions"][:steps]

    def play(self, bouts: int = 1, policy: Callable | None = None, max_steps: int | None = None) -> list[float]:
        """Returns of the first ``bouts`` scored bouts (or levels: 1.0 solved, 0.0 not, for
        Sokoban): played by the agent as its evaluation did, or by ``policy`` (observation ->
        action, an int) through :meth:`env` on the same starts, ``max_steps`` steps at most."""
        check_bouts(bouts)
        if policy is None:
            self.check_weights()
        if policy is None and max_steps is None:
            return self.play_scored(bouts)
        return self.loop_bouts(bouts, policy, max_steps)

    def filter(self, frames, actions, **mind_options):
        """A fresh mind (:meth:`mind`, with ``mind_options``) that has seen an episode's ``frames``
        (T + 1, as :meth:`env` gives them) and the T ``actions`` taken at all but the last, as it
        would have while playing it: ``mind.plan(frames[-1])`` then plans from that state. The
        scores a plan returns: World Models' controller's, PlaNet's CEM mean for the first step,
        MCTS's root visit counts (plus half the prior where counts tie)."""
        if len(frames) != len(actions) + 1:
            raise ValueError(f"pass the frames seen (T + 1) and the actions taken at all but the last (T): got "
                             f"{len(frames)} frames and {len(actions)} actions")
        mind = self.mind(**mind_options)
        if not hasattr(mind, "observe_step"):
            raise ValueError(f"{self.experiment}'s mind plans from the board it sees: `agent.solve(board)`")
        from wmthesis.envs.actions import check_actions

        env = self.env()
        n_actions = int(env.action_space.n)
        env.close()
        actions = check_actions(np.asarray(actions, dtype=None if len(actions) else np.int64), n_actions, len(actions))
        mind.reset()
        for frame, action in zip(frames[:-1], actions):
            mind.observe_step(frame, action)
        return mind

    def predict(self, frames, actions) -> dict:
        """The model's next step after an episode you give it: ``frames`` (T + 1) seen and one action
        taken at each (T + 1, the last at the last frame): the ``frame`` it predicts next, decoded
        ((H, W, 3) uint8; None without a decoder), and the ``reward`` it predicts (World Models,
        MCTS in its memory, PlaNet; Sokoban: ``predict(level, action)``)."""
        if len(actions) != len(frames):
            raise ValueError(f"pass one action per frame, the last the one whose outcome is predicted: got "
                             f"{len(frames)} frames and {len(actions)} actions")
        mind = self.filter(frames, list(actions)[:-1])
        env = self.env()
        from wmthesis.envs.actions import check_actions

        (action,) = check_actions(np.asarray(list(actions)[-1:]), int(env.action_space.n), 1)
        env.close()
        return self.step_prediction(mind, frames[-1], int(action))

    def step_prediction(self, mind, frame, action: int) -> dict:
        """The family's one step from a filtered ``mind`` at ``frame`` under ``action`` (:meth:`predict`)."""
        raise ValueError(f"{self.experiment}'s agent has no model that predicts a step")

    def check_weights(self) -> None:
        """ValueError naming the part (``vision``, ``memory``, ``controller``, ...) whose weights hold
        NaN or infinity: a damaged agent is refused, not played."""
        import torch

        for part in ("vision", "memory", "controller", "model", "value", "search"):
            module = getattr(self, part)
            if isinstance(module, torch.nn.Module):
                broken = [name for name, p in module.named_parameters() if not torch.isfinite(p).all()]
                if broken:
                    raise ValueError(f"{self.path}: the {part}'s weights hold NaN or infinity ({broken[0]}"
                                     f"{f' and {len(broken) - 1} more' if len(broken) > 1 else ''}); train it again")

    def loop_bouts(self, bouts: int, policy: Callable | None = None, max_steps: int | None = None) -> list[float]:
        """The returns of the agent's scored minds (:meth:`scored_minds`: each bout's as the
        evaluation seeded it), or of ``policy``, through :meth:`env` on the first ``bouts`` scored
        starts, one :func:`wmthesis.core.loop` each."""
        from wmthesis.core import loop

        env, returns = self.env(), []
        starts = self.scored_minds(bouts) if policy is None else \
            [(seed, PolicyMind(policy, int(env.action_space.n))) for seed in self.scored_seeds(bouts)]
        try:
            for seed, mind in starts:
                history = loop(env, mind, callbacks=[mind] if policy is None else None, seed=int(seed),
                               max_steps=max_steps, train_mode=False)
                returns.append(float(history[0]["return"]))
        finally:
            env.close()
        return returns


def check_episode(frames, actions, needed: int, n_actions: int) -> np.ndarray:
    """One action per frame (``actions[t]`` taken at ``frames[t]``), each an integer in
    ``[0, n_actions)``, at least ``needed`` of each, and uint8 frames; ValueError saying what to
    pass otherwise. Returns the actions as int64 (T,)."""
    from wmthesis.envs.actions import check_actions

    if str(getattr(frames, "dtype", "")) not in ("uint8", "torch.uint8"):  # a numpy array or a torch tensor
        raise ValueError(f"frames are uint8 images (T, H, W, 3) as the agent's env() gives them, got "
                         f"{getattr(frames, 'dtype', type(frames).__name__)}")
    actions = check_actions(np.asarray(actions), n_actions, len(actions))
    if len(actions) != len(frames):
        raise ValueError(f"pass one action per frame (actions[t] is the action taken at frames[t]): got {len(frames)} "
                         f"frames and {len(actions)} actions")
    if len(frames) < needed:
        raise ValueError(f"{len(frames)} frames are too few: context + horizon needs {needed} (pass more frames, or a "
                         "shorter context or horizon)")
    return actions


class PolicyMind:
    """A plain policy (observation -> action in [0, n_actions)) as a mind: one-hot scores of its action."""

    def __init__(self, policy: Callable, n_actions: int):
        self.policy, self.n_actions = policy, n_actions

    def plan(self, state, train_mode: bool = True, debug_mode: bool = False):
        import numpy as np

        action = self.policy(state)
        if isinstance(action, bool) or not isinstance(action, (int, np.integer)) or not 0 <= action < self.n_actions:
            raise ValueError(f"the policy must return an action in [0, {self.n_actions}), got {action!r}")
        scores = np.zeros(self.n_actions)
        scores[int(action)] = 1.0
        return scores


__all__ = ["check_episode", "agent_file", "load", "TrainedAgent", "PolicyMind"]
