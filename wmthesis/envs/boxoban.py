"""Level sources: DeepMind's Boxoban levels (10x10, 4 boxes; Apache-2.0), the field's Sokoban
benchmark, and :func:`load_levels`, which turns any source (a Boxoban name, a text file, boards)
into boards for ``SokobanEnv(levels=...)``.

The package carries a subset in ``boxoban_levels/`` (gzipped text, licence beside it):

| set | files | levels |
|---|---|---|
| ``unfiltered-train`` | 000-019 | 20,000 |
| ``unfiltered-valid`` | 000-009 | 10,000 |
| ``medium-train`` | 000-019 | 20,000 |
| ``medium-valid`` | 000-009 | 10,000 |

A source names a set and optionally its files: ``"boxoban-unfiltered-valid"`` (every file),
``"boxoban-medium-valid:005-009"`` (files 005 to 009), ``"boxoban-unfiltered-train:3"``.
Level ``k`` of a source is level ``k % 1000`` of its ``k // 1000``-th file, so a source's levels
keep one order. The upstream unfiltered *test* and *hard* sets are not here on purpose: they are
kept for an external check of the agent, and a source naming them is refused.

    >>> levels = boxoban_levels("boxoban-unfiltered-valid:000")
    >>> len(levels), levels[0].shape
    (1000, (10, 10))
"""
from __future__ import annotations

import functools
import gzip
import re
from importlib import resources
from pathlib import Path

import numpy as np

from wmthesis.envs.levels import LevelError, check_board, parse_level, parse_levels, read_levels

SETS = {"unfiltered-train": 20, "unfiltered-valid": 10, "medium-train": 20, "medium-valid": 10}
HELD_OUT = ("unfiltered-test", "hard")  # kept for an external check: never read here
LEVELS_PER_FILE = 1000
# Which files serve which purpose. Development decisions
# are measured on the validation files only; the reported figures come from the report files,
# which no decision looked at; training uses our generator (the Boxoban train files are free to
# use). The upstream unfiltered test and hard sets are not in the package.
BOXOBAN_SPLITS = {
    "validation": {"unfiltered": "boxoban-unfiltered-valid:000-001", "medium": "boxoban-medium-valid:000-001"},
    "report": {"unfiltered": "boxoban-unfiltered-valid:005-009", "medium": "boxoban-medium-valid:005-009"},
}


def level_folder() -> Path:
    """The folder of the vendored levels (``unfiltered/train/000.txt.gz`` ...)."""
    return Path(str(resources.files("wmthesis.envs") / "boxoban_levels"))


def parse_source(source: str) -> tuple[str, list[int]]:
    """``"boxoban-SET[:FILES]"`` -> (set, file numbers); FILES is ``N``, ``N-M`` or a comma list
    of those. A held-out set, an unknown set or a file outside the set raises ValueError."""
    match = re.fullmatch(r"boxoban-([a-z]+(?:-[a-z]+)?)(?::([\d,\- ]+))?", source)
    if match is None:
        raise ValueError(f"level source {source!r}: expected boxoban-SET or boxoban-SET:FILES "
                         f"(e.g. boxoban-medium-valid:005-009); sets: {', '.join(SETS)}")
    name, files = match[1], match[2]
    if name in HELD_OUT or any(name.startswith(held) for held in HELD_OUT):
        raise ValueError(f"level source {source!r}: the {name} set is kept for an external check of the agent "
                         "and is not part of this package; use the valid sets for figures")
    if name not in SETS:
        raise ValueError(f"level source {source!r}: unknown set {name!r}; valid: {', '.join(SETS)}")
    numbers = list(range(SETS[name])) if files is None else _file_numbers(files, source)
    outside = [n for n in numbers if n >= SETS[name]]
    if outside:
        raise ValueError(f"level source {source!r}: {name} holds files 000-{SETS[name] - 1:03d} here, "
                         f"not {', '.join(f'{n:03d}' for n in outside)}")
    return name, numbers


def _file_numbers(text: str, source: str) -> list[int]:
    numbers = []
    for part in text.split(","):
        low, _, high = part.strip().partition("-")
        if not low.isdigit() or (high and not high.isdigit()) or (high and int(high) < int(low)):
            raise ValueError(f"level source {source!r}: {part!r} is not a file number or a range low-high")
        numbers.extend(range(int(low), int(high or low) + 1))
    return list(dict.fromkeys(numbers))


def boxoban_file(name: str, number: int) -> Path:
    """The path of file ``number`` of set ``name`` (e.g. ``"medium-valid"``, 5)."""
    kind, split = name.split("-")
    return level_folder() / kind / split / f"{number:03d}.txt.gz"


@functools.lru_cache(maxsize=64)
def _read_file(path: Path) -> tuple[np.ndarray, ...]:
    with gzip.open(path, "rt") as f:
        boards = parse_levels(f.read(), str(path))
    if len(boards) != LEVELS_PER_FILE:
        raise LevelError(f"{path}: {len(boards)} levels, a Boxoban file holds {LEVELS_PER_FILE}")
    return tuple(boards)


def boxoban_levels(source: str) -> list[np.ndarray]:
    """The boards (each uint8 (10, 10) codes) of a source (:func:`parse_source`), in its order."""
    name, numbers = parse_source(source)
    return [board for number in numbers for board in _read_file(boxoban_file(name, number))]


def load_levels(source) -> list[np.ndarray]:
    """A level source -> its boards: ``"boxoban-SET[:FILES]"`` (the vendored Boxoban levels,
    above), the path of a text file (:func:`read_levels`), or boards
    (each (h, w) codes, or a level's text), each checked (:func:`check_board`)."""
    if isinstance(source, str) and source.startswith("boxoban-"):
        return boxoban_levels(source)
    if isinstance(source, (str, Path)):
        return read_levels(source)
    boards = [parse_level(b, f"level {i}") if isinstance(b, str) else np.asarray(b, np.uint8)
              for i, b in enumerate(source)]
    if not boards:
        raise LevelError("the level source holds no levels")
    for i, board in enumerate(boards):
        check_board(board, f"level {i}")
    return boards


__all__ = ["BOXOBAN_SPLITS", "load_levels", "SETS", "HELD_OUT", "LEVELS_PER_FILE", "level_folder", "parse_source", "boxoban_file", "boxoban_levels"]
