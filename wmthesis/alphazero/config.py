"""The config of World Models + AlphaZero (thesis 4.3): search, self-play and training, the author's
values as defaults (profiles: :mod:`wmthesis.config`)."""
from __future__ import annotations

import math

from dataclasses import dataclass


@dataclass(frozen=True)
class AlphaZeroConfig:
    """World Models + AlphaZero (thesis 4.3; the author's values): MCTS with c = 1.0, 50
    simulations (or a ``timeout`` in seconds), Dirichlet noise 0.3 mixed in at 0.25 while
    training, gamma 0.99, the subtree reused; self-play proportional to the visit counts for 12
    warm-up steps, then greedy (tests greedy); the latest 1000 games kept; every 10 games, 5
    epochs of value MSE + policy cross-entropy + L2 1e-4, SGD Nesterov lr 1e-2, momentum 0.9,
    batch 256; value targets are the returns.

    Not stated in the thesis: the number of ``games``, ``max_steps`` (None: full bouts, ~1,780
    agent steps), the no-op starts (as the controller's evaluation), greedy tests every
    ``test_every`` games, ``eval_episodes`` after training (of ``eval_max_steps``). Beyond the
    thesis: ``search_depth`` and ``root_actions`` (:class:`~wmthesis.alphazero.mcts.MCTS`'s
    ``max_depth`` and ``root_actions``) and ``decision_beta`` (greedy games choose by
    :func:`~wmthesis.alphazero.selfplay.prior_and_q`, not by visit counts), ``root="gumbel"``
    (:mod:`~wmthesis.alphazero.gumbel`: the root samples ``considered`` actions and halves them, acts
    on the survivor, and the heads learn its improved policy; ``gumbel_scale`` on its noise,
    ``c_scale`` and ``c_visit`` in its sigma); the ``improved`` variant: ``normalize_q`` (min-max Q, MuZero), ``tie_break="q"``
    (equal visit counts go to the higher root Q, not to the first action),
    ``value_target="n-step"`` (``n_step``-step bootstrapped targets instead of ``"monte-carlo"``
    returns) and ``reuse_tree=False``. The ``learned-reward`` variant adds ``reward_model``: the
    search's rewards come from an MLP classifier (``reward_hidden`` units, rewards
    ``-reward_range..reward_range``) of the reward ``reward_delay`` steps after each action,
    pretrained for ``reward_pretrain_epochs`` on the random rollouts, then ``reward_epochs``
    on them and the self-play replay after every training round (Adam ``reward_lr``), its
    rare rewards weighted up in the loss (``reward_weighted``). The
    ``imitation`` variant sets ``expert_games``: before self-play, the heads train for
    ``expert_epochs`` on that many greedy games (of ``eval_max_steps``) of an expert, notebook
    02's controller, as AlphaGo's policy started from expert games; they stay in the replay.
    The ``own-reward`` variant is imitation with a reward model of the step's own reward
    (``reward_delay=0``) trained with a plain loss (``reward_weighted=False``: calibrated
    expected rewards) on the random rollouts and the agent's own games, the expert's included.
    The ``own-memory`` variant sets ``memory_games``: the expert first plays that many greedy bouts
    and the search's memory learns from them and the random rollouts together
    (:mod:`wmthesis.alphazero.expert_memory`).
    """

    c: float = 1.0
    simulations: int = 50
    timeout: float | None = None
    search_depth: int | None = None      # beyond the thesis: the tree grows at most this many edges deep
    root_actions: int | None = None      # beyond the thesis: the root chooses among its k most probable actions
    decision_beta: float | None = None   # beyond the thesis: greedy games play argmax log P + beta (Q - V), not the most visited
    root: str | None = None              # beyond the thesis: "gumbel", Gumbel MuZero's root (None: the thesis's PUCT)
    considered: int | None = None        # the Gumbel root's k actions sampled (None: 16, at most the actions)
    gumbel_scale: float = 1.0            # the Gumbel root's noise (0: the prior's top k, no sampling)
    c_scale: float = 0.1                 # the Gumbel root's sigma: how far Q moves the prior's logits ...
    c_visit: float = 50.0                # ... times (c_visit + the most visits an action has)
    gamma: float = 0.99
    dirichlet_alpha: float = 0.3
    noise_ratio: float = 0.25
    normalize_q: bool = False
    reuse_tree: bool = True
    tie_break: str = "first"             # equal visit counts: "first" action (argmax), higher root "q" or "prior"
    warmup: int = 12
    replay_games: int = 1000
    train_every: int = 10
    epochs: int = 5
    batch_size: int = 256
    lr: float = 1e-2
    momentum: float = 0.9
    l2: float = 1e-4
    value_target: str = "monte-carlo"
    n_step: int = 10
    games: int = 1000                    # not stated in the thesis
    max_steps: int | None = None         # None: full-length bouts
    noop_max: int = 30
    test_every: int = 10                 # 0: no greedy tests while training
    test_episodes: int = 1
    eval_episodes: int = 10
    eval_max_steps: int | None = None    # the final evaluation's games; None: full bouts
    reward_model: bool = False           # learned-reward variant: the search's rewards from a RewardModel
    reward_delay: int = 2                # Boxing: a punch lands two agent steps after FIRE
    reward_hidden: int = 64
    reward_range: int = 2
    reward_lr: float = 1e-3
    reward_pretrain_epochs: int = 6
    reward_epochs: int = 2
    reward_weighted: bool = True         # class weights sqrt(N / (K N_k)) in the reward model's loss
    expert_games: int = 0                # imitation variant: pretrain the heads on this many expert games
    expert_epochs: int = 30
    memory_games: int = 0                # own-memory variant: the memory also learns this many expert bouts

    def __post_init__(self):
        """Refuse a search that cannot run, before anything plays: an unknown root or tie break, a
        Gumbel root without an integer budget of 2 simulations or more, or fewer than 2 actions considered."""
        if self.tie_break not in TIE_BREAKS:
            raise ValueError(f"unknown tie_break {self.tie_break!r}; valid: {', '.join(TIE_BREAKS)}")
        if self.root not in (None, *ROOTS):
            raise ValueError(f"unknown root {self.root!r}; valid: {', '.join(ROOTS)} (None: the thesis's puct)")
        if self.root == "gumbel":
            if isinstance(self.simulations, bool) or not isinstance(self.simulations, int) or self.simulations < 2:
                raise ValueError(f"a Gumbel root needs an integer budget of at least 2 simulations, got {self.simulations!r}")
            if self.considered is not None and (isinstance(self.considered, bool) or not isinstance(self.considered, int)
                                                or self.considered < 2):
                raise ValueError(f"a Gumbel root considers an integer number of actions, at least 2, got {self.considered!r}")
            if not (self.gumbel_scale >= 0 and self.c_scale > 0 and self.c_visit >= 0):
                raise ValueError(f"a Gumbel root needs gumbel_scale >= 0, c_scale > 0 and c_visit >= 0, got "
                                 f"{self.gumbel_scale!r}, {self.c_scale!r}, {self.c_visit!r}")


@dataclass(frozen=True)
class DiagnosisConfig:
    """The diagnosis of a run (``boxing-wm-alphazero``'s recipe): the memory's reward error measured
    along the first ``depth`` steps of the search's paths."""
    depth: int = 10


TIE_BREAKS = ("first", "q", "prior")  # equal visit counts go to: the first action, the higher Q, the higher prior
ROOTS = ("puct", "gumbel")  # the thesis's PUCT root, Gumbel MuZero's (wmthesis.alphazero.gumbel)

def search_settings(profile: str | None, text: str | None = None) -> dict:
    """The search's root settings: ``text`` (``"root=gumbel,c_scale=0.03"``: fields of
    :class:`AlphaZeroConfig`), or the profile's ``mcts_search``;
    ValueError in one line for a field that is not the root's or a value it refuses."""
    from wmthesis.budget_curves import BudgetCurveConfig  # light, as this module is: the command line checks first
    from wmthesis.config import for_profile

    pairs = for_profile(BudgetCurveConfig, profile).mcts_search if text is None else \
        [item.split("=", 1) for item in text.split(",") if item.strip()]
    settings = {}
    for pair in pairs:
        if len(pair) != 2 or pair[0].strip() not in SEARCH_FIELDS:
            raise ValueError(f"search setting {'='.join(pair)!r} is not NAME=VALUE of {', '.join(SEARCH_FIELDS)}")
        name, value = pair[0].strip(), str(pair[1]).strip()
        settings[name] = value if name in ("root", "tie_break") else _number(name, value)
    AlphaZeroConfig(simulations=2, **settings)  # refuses an unknown root or a setting it cannot run with
    return settings


def _number(name: str, text: str) -> float | int:
    """A numeric root setting from ``text``: ``considered`` a whole number, the others finite and at
    least 0 (``c_scale`` above 0); ValueError in one line otherwise, whichever root is asked for."""
    try:
        value = int(text) if name == "considered" else float(text)
    except ValueError:
        raise ValueError(f"search setting {name}={text!r} is not {'a whole number' if name == 'considered' else 'a number'}") from None
    if not math.isfinite(value) or value < 0 or (name == "c_scale" and value == 0):
        raise ValueError(f"search setting {name}={text!r}: it must be a finite number "
                         f"{'above 0' if name == 'c_scale' else 'of at least 0'}")
    return value


SEARCH_FIELDS = ("root", "tie_break", "considered", "gumbel_scale", "c_scale", "c_visit")


def search_tag(search: dict) -> str:
    """A search's settings in a row: ``"puct"`` (the agent's own) or ``"gumbel c_scale=0.03"``."""
    rest = " ".join(f"{k}={v:g}" if isinstance(v, float) else f"{k}={v}" for k, v in search.items() if k != "root")
    return " ".join(filter(None, [search.get("root", "puct"), rest]))


__all__ = ["AlphaZeroConfig", "DiagnosisConfig", "ROOTS", "TIE_BREAKS", "SEARCH_FIELDS", "search_settings", "search_tag"]
