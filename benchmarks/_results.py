"""What the benchmark scripts share: the machine's metadata, the results file and a text table.

Scripts put their own folder on ``sys.path`` and ``from _results import ...``.
"""
from __future__ import annotations

import json
import numbers
import os
import platform
from datetime import date
from importlib import metadata
from pathlib import Path


def torch_version() -> str | None:
    """torch's version, read without importing torch (a script may set up OpenMP first)."""
    try:
        return metadata.version("torch")
    except metadata.PackageNotFoundError:
        return None


def load_average() -> list[float] | None:
    """The 1, 5 and 15 minute load averages, or None where the system has none."""
    return list(os.getloadavg()) if hasattr(os, "getloadavg") else None


def machine_meta(**extra) -> dict:
    """The run's own settings (``extra``), then date, machine, cores, python, torch and load
    average; a key in ``extra`` wins over the common one."""
    common = dict(date=date.today().isoformat(), machine=platform.machine(), cores=os.cpu_count(),
                  python=platform.python_version(), torch=torch_version(), load_average=load_average())
    meta = dict(extra)
    for key, value in common.items():
        meta.setdefault(key, value)
    return meta


def _plain(value):
    """What ``json`` cannot write itself: numpy (or torch) numbers and arrays as plain ones."""
    if hasattr(value, "tolist"):
        return value.tolist()
    return float(value)


def write_json(path: Path | str, data: dict) -> None:
    """Write ``data`` as indented JSON with a trailing newline (folder created, file replaced
    whole through ``PATH.tmp``) and say so."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(data, indent=2, default=_plain) + "\n")
    tmp.replace(path)
    print(f"wrote {path}")


def write_results(path: Path | str, meta: dict, rows: list[dict]) -> None:
    """Write ``{"meta": meta, "results": rows}`` to ``path`` (:func:`write_json`)."""
    write_json(path, {"meta": meta, "results": rows})


def _cell(value) -> str:
    """A table cell: blank for None, whole numbers from 100 up, else 3 significant digits."""
    if value is None:
        return ""
    if isinstance(value, numbers.Real) and not isinstance(value, numbers.Integral):
        return f"{value:.0f}" if abs(value) >= 100 else f"{value:.3g}"
    return str(value)


def print_table(rows: list[dict], columns: list[str] | None = None) -> None:
    """Print ``rows`` as a plain aligned table: a header of the keys in ``columns`` (default:
    every key, first seen first), then a line a row; numbers to the right, a missing key blank."""
    columns = list(columns or dict.fromkeys(key for row in rows for key in row))
    cells = [[_cell(row.get(key)) for key in columns] for row in rows]
    widths = [max([len(key)] + [len(line[i]) for line in cells]) for i, key in enumerate(columns)]
    right = [[isinstance(row.get(key), numbers.Number) for key in columns] for row in rows]
    header_right = [any(flags[i] for flags in right) for i in range(len(columns))]
    for line, flags in [(columns, header_right)] + list(zip(cells, right)):
        print("  ".join(text.rjust(width) if flag else text.ljust(width)
                        for text, width, flag in zip(line, widths, flags)).rstrip())
