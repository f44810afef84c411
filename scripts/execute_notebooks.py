"""Execute the notebooks in place, so that they are committed with their outputs.

Every notebook of ``notebooks/`` (or the ones named) runs top to bottom in a fresh kernel
(nbclient) in a temporary working folder (the files it writes are not kept); its outputs
replace the old ones, and each code cell records the sha256 of the source it ran in
``metadata.spgeo.source_sha256``.  ``tests/test_notebooks.py`` checks that the committed
outputs are current (every code cell ran, in order, from the source it shows) and that the
figures stay small.

    python3 scripts/execute_notebooks.py [notebooks/NAME.ipynb ...]
"""
from __future__ import annotations

import hashlib
import sys
import tempfile
from pathlib import Path

import nbclient
import nbformat

ROOT = Path(__file__).resolve().parents[1]


def source_sha256(source: str) -> str:
    """The hash a code cell's source is recorded under."""
    return hashlib.sha256(source.encode("utf-8")).hexdigest()


def execute(path: Path) -> None:
    """Run ``path`` in a fresh kernel and write it back with outputs and source hashes."""
    nb = nbformat.read(path, as_version=4)
    with tempfile.TemporaryDirectory(prefix="spgeo-nb-") as work:
        nbclient.NotebookClient(nb, timeout=600, kernel_name="python3",
                                resources={"metadata": {"path": work}}).execute()
    for cell in nb.cells:
        if cell.cell_type == "code":
            cell.metadata["spgeo"] = {"source_sha256": source_sha256(cell.source)}
    tmp = path.with_suffix(".ipynb.tmp")
    nbformat.write(nb, tmp)
    tmp.replace(path)
    print(f"executed {path.relative_to(ROOT)}")


def main(argv) -> int:
    paths = [Path(p).resolve() for p in argv] or sorted((ROOT / "notebooks").glob("*.ipynb"))
    for path in paths:
        execute(path)
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
