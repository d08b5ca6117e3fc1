"""Variants of an experiment, declared one way everywhere.

A :class:`Variant` is a name, one line saying what it is, the changes it makes (to the
experiment's configs: a dict of fields, or of configs by name where an experiment has several),
the variant it builds on (whose changes come first and whose run it may start from) and its
status: the experiment's ``default`` (its best recipe, as chosen on validation) or an
``ablation`` its notebook shows. Each experiment declares one :class:`Variants` registry.

What every other variant measured, and the commit where its code last lived, is in
``docs/findings/<experiment>.md``: asking for a removed variant says so.

    PLANET_BOXING = Variants("planet-boxing",
        Variant("unchanged", "PlaNet as published (5.6.1)", default=True),
        Variant("free-nats", "KL scale 0.03, free nats 12 (5.6.4)", dict(kl_scale=0.03, free_nats=12.0)))
    PLANET_BOXING.changes("free-nats")  # {'kl_scale': 0.03, 'free_nats': 12.0}
"""
from __future__ import annotations

from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field

FINDINGS = "docs/findings"


@dataclass(frozen=True)
class Variant:
    """One variant: ``name``, ``about`` (one line), its config ``changes``, the variant it
    ``builds_on`` (None: the experiment's defaults) and whether it is the ``default``."""
    name: str
    about: str
    changes: Mapping = field(default_factory=dict)
    builds_on: str | None = None
    default: bool = False

    @property
    def status(self) -> str:
        return "default" if self.default else "ablation"


class Variants(Mapping):
    """An experiment's variants by name (in the order declared), exactly one of them the default.
    ``root``: the variant whose runs keep the experiment's own folders (its first recipe, where
    later recipes came as variants); every other variant's runs go to folders of its name."""

    def __init__(self, experiment: str, *variants: Variant, root: str | None = None):
        self.experiment = experiment
        self._variants = {v.name: v for v in variants}
        if len(self._variants) != len(variants):
            raise ValueError(f"{experiment}: a variant name is declared twice")
        if root is not None and root not in self._variants:
            raise ValueError(f"{experiment}: the root {root!r} is not declared")
        self.root = root
        defaults = [v.name for v in variants if v.default]
        if len(defaults) != 1:
            raise ValueError(f"{experiment}: exactly one default variant, got {defaults}")
        for v in variants:
            if v.builds_on is not None and v.builds_on not in self._variants:
                raise ValueError(f"{experiment}: {v.name!r} builds on {v.builds_on!r}, which is not declared")
        self.default = self._variants[defaults[0]]

    @property
    def findings(self) -> str:
        """Where the variants that left the code keep their numbers."""
        return f"{FINDINGS}/{self.experiment}.md"

    def __getitem__(self, name: str) -> Variant:
        return self._variants[name]

    def __iter__(self) -> Iterator[str]:
        return iter(self._variants)

    def __len__(self) -> int:
        return len(self._variants)

    def check(self, name: str | None) -> Variant:
        """The variant ``name`` (None: the default); an unknown name raises ValueError listing the
        valid ones and naming the findings file where removed variants' numbers live."""
        if name is None:
            return self.default
        if name not in self._variants:
            raise ValueError(f"unknown variant {name!r} of {self.experiment}; valid: {', '.join(self._variants)} "
                             f"(variants no longer in the code, with their numbers: {self.findings})")
        return self._variants[name]

    def folder_name(self, name: str | None) -> str | None:
        """The variant ``name``'s name in its folders and metrics (None: the default): None for
        the :attr:`root`'s runs, which keep the experiment's own folders."""
        name = self.check(name).name
        return None if name == self.root else name

    def lineage(self, name: str | None) -> list[Variant]:
        """The variant ``name`` and those it builds on, the first built on first."""
        chain = [self.check(name)]
        while chain[0].builds_on is not None:
            chain.insert(0, self._variants[chain[0].builds_on])
        return chain

    def changes(self, name: str | None, part: str | None = None) -> dict:
        """The changes of ``name`` over those it builds on (later ones win); ``part``: only those
        of one config, where the changes are given per config."""
        merged: dict = {}
        for variant in self.lineage(name):
            changes = variant.changes if part is None else variant.changes.get(part, {})
            for key, value in changes.items():  # a config's changes given per config merge too
                both = isinstance(value, Mapping) and isinstance(merged.get(key), Mapping)
                merged[key] = {**merged[key], **value} if both else value
        return merged

    def rows(self) -> list[list[str]]:
        """A row per variant: name, status, what it builds on, what it is (for a table)."""
        return [[v.name, v.status, v.builds_on or "", v.about] for v in self._variants.values()]


def no_variant(experiment: str, variant: str | None) -> None:
    """Refuse a variant for an experiment that has none (every recipe takes one, as ``reproduce`` does)."""
    if variant is not None:
        raise ValueError(f"experiment {experiment!r} has no variants, got {variant!r}")


@dataclass(frozen=True)
class Levers:
    """An experiment's levers, the changes a choice may adopt on its validation split:
    ``changes`` (lever name -> its changes); ``run(levers, *, profile, seeds, variant, count,
    workers, progress)`` plays them, ``{seed: {lever: result}}``; ``lines(results)`` says one
    seed's results in lines."""
    changes: Mapping
    run: object
    lines: object


__all__ = ["Levers", "Variant", "Variants", "FINDINGS", "no_variant"]
