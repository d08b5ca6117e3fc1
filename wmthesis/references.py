"""Published figures shown beside ours, each written once with its source: random and human play,
the thesis's own results, the Atari-100k agents, and the best Sokoban agents.

A figure is a :class:`Reference` (name, value or words, source). Each experiment's declaration
names the figures its results are shown beside (:func:`published_figures`) (the summary's column and every
``metrics.json``'s ``reference``); :func:`human` and :func:`random_play` give one game's.
Other agents' figures are not on our levels or bouts, nor at our budget: they give the scale.
"""
from __future__ import annotations

from typing import NamedTuple

IRIS = "eloialonso/iris results/data"


class Reference(NamedTuple):
    """A published figure: who, the number (or the words where the source gives none), where, the
    budget it was reached with (its agent steps in the real environment, in the source's words;
    empty where it states none), and the source's own words where the figure is our reading of them."""
    name: str
    value: float | str
    source: str
    budget: str = ""
    quote: str = ""  # the source's own words, where ``value`` is our reading of them


RANDOM = {"boxing": Reference("random", 0.1, f"{IRIS}/RANDOM.json"),
          "freeway": Reference("random", 0.0, f"{IRIS}/RANDOM.json")}
HUMAN = {"boxing": Reference("human", 12.1, f"{IRIS}/HUMAN.json"),
         "freeway": Reference("human", 29.6, f"{IRIS}/HUMAN.json")}

THESIS_WORLD_MODELS = Reference("thesis World Models", "above 18 on average across 5 runs", "thesis 5.4.1")
THESIS_ALPHAZERO = Reference("thesis World Models + AlphaZero", "did not train to properly plan", "thesis 5.4.2")
THESIS_PLANET_BOXING = Reference("thesis PlaNet", "around 30", "thesis 5.6.4 (KL scale 0.03, free nats 12)")
THESIS_PLANET_BOXING_SCORE = 30.0  # "around 30", as a line in the figures
THESIS_PLANET_FREEWAY = Reference("thesis PlaNet", "failed to solve the task", "thesis 5.6.5")
THESIS_SOKOBAN = Reference("thesis", "0 levels solved", "thesis 5.3.1", quote="The controller model failed to learn "
                           "how to solve any level, it behaved comparably to a random play")
THESIS_SOKOBAN_VISION = Reference("thesis", "reconstructions that show the frame, its player included (most frames)",
                                  "thesis 5.3.1 (Fig. 54)", quote="The vision model successfully learned to encode high "
                                  "dimensional observations into low dimensional latent states")
THESIS_PLANET_SOKOBAN = Reference("thesis PlaNet", "did not capture Sokoban dynamics: future predictions are blurred, "
                                  "multiple agents appear", "thesis 5.5.1 (Fig. 58)", quote="PlaNet did not capture "
                                  "Sokoban dynamics too. In the figure below (Fig. 58) future predictions are blurred, "
                                  "multiple agents appear and other artifacts, like changing block type, are present")
THESIS_PLANET_SEARCH = Reference("thesis PlaNet", "Random search resulted in the best divergence scale being around 0.03 "
                                 "[...] The best free nats turned out to be 12", "thesis 5.6.3-5.6.4; the trials judged "
                                 "by eye, the author's note there says")
THESIS_PLANNING = Reference("thesis", "planning carries the promise of increasing performance just by increasing the "
                            "computational budget for searching for good actions", "thesis, chapter 1")

# The thesis judged Sokoban's World Models by eye (5.3) and reported no score.
THESIS_SOKOBAN_WM = {
    "5.3.1 vision": "reconstructions resemble the frames (Fig. 54)",
    "5.3.1 memory": "dynamics not learned: the agent disappears, blocks change type, pushes not modelled (Fig. 55); "
                    "deterministic memory no better",
    "5.3.1 controller": "solved no level, comparable to random play",
    "5.3.2 grid states": "no improvement over 5.3.1",
    "5.3.3 auxiliary heads": "reward and value not learned (sparse rewards); no improvement",
}

ATARI_100K_STEPS = "100k"  # agent steps (400k frames) each Atari-100k agent learns from
ATARI_100K = {  # agents trained on 100k agent steps, on GPUs
    "boxing": (Reference("SimPLe (Atari 100k)", 7.8, f"{IRIS}/SimPLe.json", ATARI_100K_STEPS),
               Reference("EfficientZero (Atari 100k)", 52.7, f"{IRIS}/EfficientZero.json", ATARI_100K_STEPS),
               Reference("IRIS (Atari 100k)", 70.1, f"{IRIS}/IRIS.json", ATARI_100K_STEPS),
               Reference("DreamerV3 (Atari 100k)", 78.0, "danijar/dreamerv3 scores", ATARI_100K_STEPS),
               Reference("STORM (Atari 100k)", 79.7, "weipu-zhang/STORM results/storm.json", ATARI_100K_STEPS),
               Reference("DIAMOND (Atari 100k)", 86.9, "eloialonso/diamond results/data/DIAMOND.json", ATARI_100K_STEPS),
               Reference("REM (Atari 100k)", 87.5, "leor-c/REM results/data/REM.json", ATARI_100K_STEPS),
               Reference("Simulus (Atari 100k)", 93.5, "leor-c/Simulus results/data/atari/Simulus.json", ATARI_100K_STEPS)),
    "freeway": (Reference("SimPLe (Atari 100k)", 16.7, f"{IRIS}/SimPLe.json", ATARI_100K_STEPS),
                Reference("EfficientZero (Atari 100k)", 21.8, f"{IRIS}/EfficientZero.json", ATARI_100K_STEPS),
                Reference("IRIS (Atari 100k)", 31.1, f"{IRIS}/IRIS.json", ATARI_100K_STEPS),
                Reference("Simulus (Atari 100k)", 31.9, "leor-c/Simulus results/data/atari/Simulus.json", ATARI_100K_STEPS),
                Reference("REM (Atari 100k)", 32.3, "leor-c/REM results/data/REM.json", ATARI_100K_STEPS),
                Reference("DIAMOND (Atari 100k)", 33.3, "eloialonso/diamond results/data/DIAMOND.json", ATARI_100K_STEPS),
                Reference("DreamerV3 (Atari 100k)", 0.0, "danijar/dreamerv3 scores", ATARI_100K_STEPS)),
}


def best_atari_100k(game: str) -> Reference:
    """The highest published Atari-100k score on ``game`` (:data:`ATARI_100K`)."""
    return max(ATARI_100K[game], key=lambda ref: float(ref.value))


# PlaNet's public code: its defaults for every task (planet/scripts/configs.py; 64x64 frames and a
# first convolution of 32 channels in its networks), the configuration a reader would start from.
PLANET_PUBLIC = "google-research/planet planet/scripts/configs.py"
PLANET_PUBLIC_DEFAULTS = {
    "frames": "64x64, 5 bits", "encoder depth (first convolution's channels)": "32", "batch (chunks x steps)": "50 x 50",
    "latent overshooting distance": "0", "random seed bouts": "5", "updates between collected bouts": "5,000",
    "updates in all": "not capped (runs until stopped)", "agent steps collected": "not capped",
    "CEM: candidates x horizon x iterations": "1000 x 12 x 10",
}


DRC = "AlignmentResearch/learned-planner plot/data/drc33_*_success_across_thinking_steps.csv"
BOXOBAN = {  # the best published agent on each kind of Boxoban level, 120-step episodes
    "unfiltered": Reference("DRC(3,3), 2e9 steps, Boxoban unfiltered test", 99.3, DRC, "2e9"),
    "medium": Reference("DRC(3,3), 2e9 steps, Boxoban medium valid", "76.6-81.3", DRC, "2e9"),
}
THINKER = Reference("Thinker, 5e7 frames, Boxoban unfiltered train", 94.5, "Chung et al. 2023, Table 1", "5e7")
# The Boxoban table's published rows: (agent, unfiltered %, medium %, data, source). Not our
# levels (their test sets; our report files are valid 005-009): given for scale.
BOXOBAN_PUBLISHED = (
    ("DRC(3,3), model-free", "99.3 (test)", "76.6-81.3 (valid)", "2e9 env steps", DRC),
    ("Thinker, learned model + planning", "94.5 (train)", "", "5e7 frames", "Chung et al. 2023, Table 1"),
    ("MuZero", "21 (train)", "", "5e7 frames", "Chung et al. 2023, Table 1"),
    ("DreamerV3", "32 (train)", "", "5e7 frames", "Chung et al. 2023, Table 1"),
    ("LevinTS, learned policy + true simulator", "100 (test)", "", "6.6e6 expansions", "Orseau et al. 2018, Table 1"),
    ("A*, box-distance heuristic, true rules", "98.9 (test, 1M nodes)", "99.998 (valid, 5M nodes)", "",
     "AlignmentResearch/boxoban-astar-solutions"),
)

# The figures each experiment's results are shown beside, named by its declaration's ``published``.
BOXING_WM_FIGURES = (RANDOM["boxing"], HUMAN["boxing"], THESIS_WORLD_MODELS)
# learning in the dream: beside the agents that learn in a model from Atari 100k's budget
BOXING_DREAM_FIGURES = (RANDOM["boxing"], HUMAN["boxing"], *(r for r in ATARI_100K["boxing"]
                                                             if r.name.split(" ")[0] in ("SimPLe", "IRIS")))
ALPHAZERO_FIGURES = (RANDOM["boxing"], HUMAN["boxing"], THESIS_ALPHAZERO)
BOXING_PLANET_FIGURES = (RANDOM["boxing"], HUMAN["boxing"], THESIS_PLANET_BOXING, *ATARI_100K["boxing"])
FREEWAY_FIGURES = (RANDOM["freeway"], HUMAN["freeway"], THESIS_PLANET_FREEWAY, *ATARI_100K["freeway"])
SOKOBAN_SEARCH_FIGURES = (THESIS_SOKOBAN, BOXOBAN["unfiltered"], THINKER)
SOKOBAN_WM_FIGURES = (Reference("thesis World Models", "0 levels solved", "thesis 5.3"),)


def published_figures(experiment: str) -> tuple[Reference, ...]:
    """The figures ``experiment``'s results are shown beside (its declaration's ``published``; none
    where it names none: the thesis judged Fig. 58 by eye, a study has no score)."""
    from wmthesis.declarations import DECLARED, resolve

    named = DECLARED[experiment].published
    return () if named is None else tuple(resolve(named))


def published(experiment: str) -> dict[str, float | str]:
    """``experiment``'s published figures as a ``metrics.json`` keeps them: name -> value."""
    return {ref.name: ref.value for ref in published_figures(experiment)}


def human(game: str) -> float:
    """Human play's score on an Atari ``game`` (boxing, freeway)."""
    return float(HUMAN[game].value)


def random_play(game: str) -> float:
    """Random play's published score on an Atari ``game`` (boxing, freeway)."""
    return float(RANDOM[game].value)


__all__ = ["Reference", "RANDOM", "HUMAN", "ATARI_100K", "BOXOBAN", "BOXOBAN_PUBLISHED", "THINKER", "BOXING_WM_FIGURES", "BOXING_DREAM_FIGURES", "ALPHAZERO_FIGURES",
           "BOXING_PLANET_FIGURES", "FREEWAY_FIGURES", "SOKOBAN_SEARCH_FIGURES", "SOKOBAN_WM_FIGURES", "published_figures",
           "THESIS_WORLD_MODELS", "THESIS_ALPHAZERO", "THESIS_PLANET_BOXING", "THESIS_PLANET_BOXING_SCORE",
           "THESIS_PLANET_FREEWAY", "THESIS_SOKOBAN", "THESIS_PLANET_SOKOBAN", "THESIS_PLANET_SEARCH", "THESIS_PLANNING",
           "THESIS_SOKOBAN_WM", "PLANET_PUBLIC", "PLANET_PUBLIC_DEFAULTS", "published", "human", "random_play", "best_atari_100k"]
