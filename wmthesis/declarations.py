"""What each experiment is, declared once: its name, the thesis section, its recipe, its variants,
the experiments it builds on, and the agent it ships. Light (no torch): the command line checks
names against these records before anything heavy loads, and ``reproduce``, ``sweep``'s order and
``wmthesis.load`` loop over them.

    EXPERIMENT = Declaration("boxing-wm", "5.4.1", "wmthesis.experiments.world_models:boxing_world_models",
                             variants="wmthesis.world_models.variants:BOXING_WM",
                             agent=AgentFile("{profile}/boxing-wm/seed{seed}/agent-{variant}.pt",
                                             "wmthesis.world_models.trained:load_trained", "boxing"))

A recipe is ``recipe(profile, seed, variant, progress) -> metrics``; a new experiment is one
recipe module and one declaration here (or, from one's own code, :func:`declare`).
"""
from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass


NO_SCORE = "wmthesis.scores:no_score"  # the score of an experiment without a headline (a study, the curves)
DEFAULT_MEASURE = "mean episode return over the evaluation episodes"


@dataclass(frozen=True)
class Names:
    """Every experiment's name, written once: code outside this module writes
    ``NAMES.boxing_wm``, never the text ``"boxing-wm"``."""
    sokoban_wm: str = "sokoban-wm"
    boxing_wm: str = "boxing-wm"
    boxing_wm_alphazero: str = "boxing-wm-alphazero"
    boxing_wm_dream: str = "boxing-wm-dream"
    planet_sokoban: str = "planet-sokoban"
    planet_boxing: str = "planet-boxing"
    planet_freeway: str = "planet-freeway"
    planet_boxing_study: str = "planet-boxing-study"
    planet_boxing_search: str = "planet-boxing-search"
    planet_boxing_agent: str = "planet-boxing-agent"
    planet_boxing_value: str = "planet-boxing-value"
    planet_freeway_value: str = "planet-freeway-value"
    sokoban_search: str = "sokoban-search"
    planning_budget: str = "planning-budget"


NAMES = Names()


def resolve(path: str):
    """``"module:name"`` -> the object it names (importing the module)."""
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


@dataclass(frozen=True)
class AgentFile:
    """Where a run's trained agent lies under ``data/`` and what loads it: ``pattern`` with
    ``{profile}``, ``{seed}``, ``{variant}`` (the variant's name) and ``{folder}`` (the variant's run
    folder prefix, ``"NAME-"``, or empty for runs in the experiment's own folders); ``loader``
    (``"module:function"``, called ``loader(path, experiment=, variant=, profile=, seed=)``); ``game``,
    the game the agent plays (a file that holds another game's agent is refused)."""
    pattern: str
    loader: str
    game: str

    def path(self, profile: str, seed: int, variant: str | None, folder: str | None) -> str:
        return self.pattern.format(profile=profile, seed=seed, variant=variant, folder=f"{folder}-" if folder else "")


@dataclass(frozen=True)
class Declaration:
    """One experiment: ``name``, the thesis ``section`` (or where beyond it), ``recipe``
    (``"module:function"``), ``variants`` (``"module:NAME"`` of its
    :class:`~wmthesis.variants.Variants`; None: it has none), ``builds_on`` (the experiments whose
    runs of the same profile and seed it uses), ``agent`` (:class:`AgentFile`; None: it ships
    no agent), ``score``, how its headline is read from its ``metrics.json`` (``"module:function"``,
    :mod:`wmthesis.scores`), ``levers`` (``"module:function"`` that makes its :class:`~wmthesis.variants.Levers`,
    measured on validation splits by ``validate``; None: it has none), ``frozen_model`` (the
    ``metrics.json`` key of the thesis CEM's bouts on the frozen model that its variants mean to
    share, by which the summary pairs them; None: variants pair by seed), ``measure`` (what its
    headline score is, in the summary's words), ``bounds`` (the range its score cannot leave: its
    interval is clipped to it; None: none) and ``choice_seeds`` (``"module:NAME"`` of the seeds its
    recipe was chosen on: their runs form rows of their own, never the reported ones; None: none),
    ``published`` (``"module:NAME"`` of the :class:`~wmthesis.references.Reference` figures its
    results are shown beside; None: none), ``agent_steps`` (``"module:function"`` reading from its
    ``metrics.json`` the real environment steps it learned from, :mod:`wmthesis.budget`; None: none
    recorded). A run without a variant runs its default."""
    name: str
    section: str
    recipe: str
    variants: str | None = None
    builds_on: tuple[str, ...] = ()
    agent: AgentFile | None = None
    score: str = "wmthesis.scores:variant_score"
    levers: str | None = None
    frozen_model: str | None = None
    measure: str = DEFAULT_MEASURE
    bounds: tuple[float, float] | None = None
    choice_seeds: str | None = None
    published: str | None = None
    agent_steps: str | None = None

    def registry(self):
        """Its :class:`~wmthesis.variants.Variants`, or None."""
        return None if self.variants is None else resolve(self.variants)


DECLARATIONS = (  # the thesis's and ours, built in; DECLARED holds them and every one declare() adds
    Declaration(NAMES.sokoban_wm, "5.3", "wmthesis.experiments.sokoban_world_models:sokoban_world_models",
                published="wmthesis.references:SOKOBAN_WM_FIGURES", score="wmthesis.scores:sokoban_world_models_scores",
                measure="percent of evaluation levels the controller solved", bounds=(0.0, 100.0),
                agent_steps="wmthesis.budget:sokoban_world_models_steps"),
    Declaration(NAMES.boxing_wm, "5.4.1", "wmthesis.experiments.world_models:boxing_world_models",
                published="wmthesis.references:BOXING_WM_FIGURES", agent_steps="wmthesis.budget:world_models_steps",
                variants="wmthesis.world_models.variants:BOXING_WM", levers="wmthesis.validation:boxing_wm_levers",
                choice_seeds="wmthesis.world_models.variants:VALIDATION_SEEDS",
                agent=AgentFile("{profile}/boxing-wm/seed{seed}/agent-{variant}.pt",
                                "wmthesis.world_models.trained:load_trained", "boxing")),
    Declaration(NAMES.boxing_wm_alphazero, "5.4.2", "wmthesis.experiments.alphazero:boxing_wm_alphazero",
                published="wmthesis.references:ALPHAZERO_FIGURES", agent_steps="wmthesis.budget:alphazero_steps",
                variants="wmthesis.alphazero.variants:VARIANTS", builds_on=(NAMES.boxing_wm,),
                score="wmthesis.scores:alphazero_scores",
                agent=AgentFile("{profile}/boxing-wm-alphazero/seed{seed}/agent-{variant}.pt",
                                "wmthesis.alphazero.trained:load_trained", "boxing")),
    Declaration(NAMES.boxing_wm_dream, "beyond", "wmthesis.experiments.world_models_dream:boxing_wm_dream",
                published="wmthesis.references:BOXING_DREAM_FIGURES", agent_steps="wmthesis.budget:dream_steps",
                variants="wmthesis.world_models.variants:DREAM_VARIANTS",
                choice_seeds="wmthesis.world_models.variants:DREAM_VALIDATION_SEEDS",
                measure="mean return over 10 full bouts, after at most 100k real agent steps",
                agent=AgentFile("{profile}/boxing-wm-dream/{folder}seed{seed}/agent.pt",
                                "wmthesis.world_models.trained:load_trained", "boxing")),
    Declaration(NAMES.planet_sokoban, "5.5.1", "wmthesis.experiments.planet:planet_sokoban",
                agent_steps="wmthesis.budget:store_steps",
                variants="wmthesis.planet.variants:PLANET_SOKOBAN",
                agent=AgentFile("{profile}/planet-sokoban/{folder}seed{seed}/agent.pt",
                                "wmthesis.planet.trained:load_trained", "sokoban-small")),
    Declaration(NAMES.planet_boxing, "5.6.1-5.6.4", "wmthesis.experiments.planet:planet_boxing",
                agent_steps="wmthesis.budget:store_steps",
                published="wmthesis.references:BOXING_PLANET_FIGURES",
                variants="wmthesis.planet.variants:PLANET_BOXING",
                agent=AgentFile("{profile}/planet-boxing/{folder}seed{seed}/agent.pt",
                                "wmthesis.planet.trained:load_trained", "boxing")),
    Declaration(NAMES.planet_freeway, "5.6.5-5.6.6", "wmthesis.experiments.planet:planet_freeway",
                agent_steps="wmthesis.budget:store_steps",
                published="wmthesis.references:FREEWAY_FIGURES",
                variants="wmthesis.planet.variants:PLANET_FREEWAY",
                agent=AgentFile("{profile}/planet-freeway/{folder}seed{seed}/agent.pt",
                                "wmthesis.planet.trained:load_trained", "freeway")),
    Declaration(NAMES.planet_boxing_study, "5.6.1-5.6.4", "wmthesis.experiments.planet_boxing:planet_boxing_study",
                score=NO_SCORE),
    Declaration(NAMES.planet_boxing_search, "5.6.3-5.6.4", "wmthesis.planet.search_run:planet_boxing_search",
                measure="the best trial's open-loop error on held-out bouts x 1000 (lower is better)"),
    Declaration(NAMES.planet_boxing_agent, "5.6.4", "wmthesis.experiments.planet_boxing:planet_boxing_agent",
                agent_steps="wmthesis.budget:store_steps",
                published="wmthesis.references:BOXING_PLANET_FIGURES",
                measure="full-bout score, CEM planner",
                score="wmthesis.scores:agent_score",
                agent=AgentFile("{profile}/planet-boxing-agent/seed{seed}/agent.pt",
                                "wmthesis.planet.trained:load_trained", "boxing")),
    Declaration(NAMES.planet_boxing_value, "beyond", "wmthesis.experiments.planet_boxing_value:planet_boxing_value",
                agent_steps="wmthesis.budget:value_steps",
                published="wmthesis.references:BOXING_PLANET_FIGURES",
                measure="full-bout score, the value's chosen round",
                variants="wmthesis.value.variants:VALUE_VARIANTS", builds_on=(NAMES.planet_boxing_agent,),
                score="wmthesis.scores:value_scores", levers="wmthesis.validation:boxing_value_levers",
                frozen_model="planet",
                agent=AgentFile("{profile}/planet-boxing-value/{folder}seed{seed}/agent.pt",
                                "wmthesis.value.trained:load_trained", "boxing")),
    Declaration(NAMES.planet_freeway_value, "beyond", "wmthesis.experiments.planet_freeway_value:planet_freeway_value",
                agent_steps="wmthesis.budget:value_steps",
                published="wmthesis.references:FREEWAY_FIGURES",
                measure="full-episode score, the value's chosen round",
                variants="wmthesis.value.variants:FREEWAY_VALUE_VARIANTS", builds_on=(NAMES.planet_freeway,),
                score="wmthesis.scores:value_scores", levers="wmthesis.validation:freeway_value_levers",
                agent=AgentFile("{profile}/planet-freeway-value/{folder}seed{seed}/agent.pt",
                                "wmthesis.value.trained:load_trained", "freeway")),
    Declaration(NAMES.sokoban_search, "beyond (ch. 1)", "wmthesis.experiments.sokoban_search:sokoban_search",
                agent_steps="wmthesis.budget:store_steps",
                published="wmthesis.references:SOKOBAN_SEARCH_FIGURES",
                measure="% of unseen 10x10 levels solved from pixels (generated; boxoban-*: Boxoban valid 005-009)",
                bounds=(0.0, 100.0),
                score="wmthesis.scores:sokoban_scores", levers="wmthesis.validation:sokoban_levers",
                agent=AgentFile("{profile}/sokoban-search/seed{seed}/pixels/state.pt",
                                "wmthesis.sokoban_search.trained:load_trained", "sokoban")),
    Declaration(NAMES.planning_budget, "ch. 1", "wmthesis.experiments.planning_budget:planning_budget",
                builds_on=(NAMES.sokoban_search, NAMES.boxing_wm_alphazero, NAMES.planet_boxing_value), score=NO_SCORE),
)
DECLARED: dict[str, Declaration] = {d.name: d for d in DECLARATIONS}


class Declared(Sequence):
    """The declared experiments' names that ``keep`` admits, in declaration order, read anew at
    each use, so an experiment :func:`declare` adds later counts everywhere."""

    def __init__(self, keep: Callable[[Declaration], bool]):
        self.keep = keep

    def names(self) -> tuple[str, ...]:
        return tuple(name for name, d in DECLARED.items() if self.keep(d))

    def __getitem__(self, index):
        return self.names()[index]

    def __len__(self) -> int:
        return len(self.names())

    def __eq__(self, other) -> bool:
        if not isinstance(other, Sequence):
            return NotImplemented
        return tuple(self) == tuple(other)

    __hash__ = None  # a live view: its members change as experiments are declared

    def __repr__(self) -> str:
        return repr(self.names())


class Of(Mapping):
    """Experiment -> ``of(its declaration)``, for the declared experiments ``keep`` admits, read
    anew at each use (as :class:`Declared`)."""

    def __init__(self, of: Callable[[Declaration], object], keep: Callable[[Declaration], bool] = lambda d: True):
        self.of, self.keep = of, keep

    def __getitem__(self, name: str):
        if name not in DECLARED or not self.keep(DECLARED[name]):
            raise KeyError(name)
        return self.of(DECLARED[name])

    def __iter__(self):
        return iter(Declared(self.keep))

    def __len__(self) -> int:
        return len(Declared(self.keep))


EXPERIMENTS = Declared(lambda d: True)
AGENTS = Declared(lambda d: d.agent is not None)


def declare(declaration: Declaration) -> Declaration:
    """Add an experiment of one's own (its recipe a ``"module:function"`` importable here):
    ``reproduce``, ``sweep``, ``summary`` and ``load`` then know it. A declared name is refused."""
    if declaration.name in DECLARED:
        raise ValueError(f"experiment {declaration.name!r} is declared already")
    unknown = [name for name in declaration.builds_on if name not in DECLARED]
    if unknown:
        raise ValueError(f"{declaration.name!r} builds on undeclared {', '.join(unknown)}; valid: {', '.join(DECLARED)}")
    DECLARED[declaration.name] = declaration
    return declaration



def check_run(experiment: str, variant: str | None = None) -> None:
    """Refuse an unknown experiment, an unknown variant, or a variant for an experiment that has
    none (ValueError in one line, listing the valid ones): light, before torch loads."""
    if experiment not in DECLARED:
        raise ValueError(f"unknown experiment {experiment!r}; valid: {', '.join(EXPERIMENTS)}")
    registry = DECLARED[experiment].registry()
    if registry is None:
        if variant:
            raise ValueError(f"experiment {experiment!r} has no variants, got {variant!r}")
    elif variant:
        registry.check(variant)


__all__ = ["NAMES", "Names", "NO_SCORE", "DEFAULT_MEASURE", "Declaration", "AgentFile", "DECLARATIONS", "DECLARED",
           "EXPERIMENTS", "AGENTS", "Declared", "Of", "declare", "resolve", "check_run"]
