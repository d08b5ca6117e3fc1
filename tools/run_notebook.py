"""Execute notebooks in place in a profile, keeping their outputs (what gets committed).

    python tools/run_notebook.py notebooks/00_environments.ipynb [--profile quick] [--timeout 3600]
"""
from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import nbformat
from nbclient import NotebookClient


def run(path: Path, profile: str, timeout: int) -> float:
    os.environ["WMTHESIS_PROFILE"] = profile
    notebook = nbformat.read(path, as_version=4)
    started = time.time()
    NotebookClient(notebook, timeout=timeout, kernel_name="python3",
                   resources={"metadata": {"path": str(path.parent)}}).execute()
    nbformat.write(notebook, path)
    return time.time() - started


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("notebooks", nargs="+", type=Path)
    parser.add_argument("--profile", default="quick", choices=("smoke", "quick", "thesis"))
    parser.add_argument("--timeout", type=int, default=3600, help="seconds per cell")
    args = parser.parse_args()
    for path in args.notebooks:
        print(f"{path}: {run(path, args.profile, args.timeout):.0f} s in profile {args.profile}")


if __name__ == "__main__":
    main()
