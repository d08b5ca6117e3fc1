"""The recipes of World Models + AlphaZero on Boxing (thesis 4.3, 5.4.2) as variants: changes to
:class:`~wmthesis.alphazero.config.AlphaZeroConfig` on top of the profile's. What each changes
and why: :mod:`wmthesis.alphazero.selfplay`. Light to import (no torch): the summary's headline
names the default from here."""
from __future__ import annotations

from wmthesis.declarations import NAMES
from wmthesis.variants import Variant, Variants

IMPROVED = dict(normalize_q=True, tie_break="q", value_target="n-step", reuse_tree=False)
VARIANTS = Variants(
    NAMES.boxing_wm_alphazero,
    Variant("unchanged", "thesis 4.3 as written", {}),
    Variant("improved", "min-max normalised Q, ties broken by Q, n-step values, no tree reuse (ours)", IMPROVED),
    Variant("learned-reward", "improved, with a reward model trained on self-play data (ours)", dict(reward_model=True),
            builds_on="improved"),
    Variant("imitation", "improved, with heads pretrained on the World Models controller's games (ours)",
            dict(expert_games=8), builds_on="improved"),
    Variant("own-reward", "imitation, the search's rewards from a reward model trained on the agent's own games (ours)",
            dict(reward_model=True, reward_delay=0, reward_weighted=False), builds_on="imitation"),
    Variant("own-memory", "own-reward, searching in a memory that learned the expert's bouts beside random play (ours)",
            dict(memory_games=20), builds_on="own-reward", default=True),
)
