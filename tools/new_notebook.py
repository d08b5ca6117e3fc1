"""Write a notebook from a list of (kind, source) cells, kind in md | code | parameters.

Used by one-off scripts that lay out a new notebook, so every notebook starts the same way:
a title, a parameters cell tagged ``parameters``, then thin cells calling wmthesis."""
from __future__ import annotations

import nbformat


def write_notebook(path: str, cells: list[tuple[str, str]]) -> None:
    notebook = nbformat.v4.new_notebook()
    notebook.metadata["kernelspec"] = {"name": "python3", "display_name": "Python 3", "language": "python"}
    for kind, source in cells:
        if kind == "md":
            notebook.cells.append(nbformat.v4.new_markdown_cell(source.strip()))
        else:
            cell = nbformat.v4.new_code_cell(source.strip())
            if kind == "parameters":
                cell.metadata["tags"] = ["parameters"]
            notebook.cells.append(cell)
    nbformat.write(notebook, path)
