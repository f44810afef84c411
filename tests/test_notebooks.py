"""The notebooks are committed executed (``scripts/execute_notebooks.py``): their
outputs must be current (every code cell ran, in order, from the source it shows),
their figures small, and they must still run (nbclient, offline)."""
import base64
import hashlib
import struct
from pathlib import Path

import pytest

NOTEBOOKS = sorted((Path(__file__).resolve().parents[1] / "notebooks").glob("*.ipynb"))
#: largest embedded figure: bytes of PNG, pixels wide
MAX_FIGURE_BYTES = 300_000
MAX_FIGURE_WIDTH = 1000


def _code_cells(nb):
    return [c for c in nb.cells if c.cell_type == "code"]


def _output_kinds(cell):
    """Output types of a cell, consecutive repeats collapsed (a kernel may split one
    cell's printing into several stream outputs)."""
    kinds = [o.get("output_type") for o in cell.get("outputs", [])]
    return [k for j, k in enumerate(kinds) if j == 0 or k != kinds[j - 1]]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_outputs_are_current(path):
    nbformat = pytest.importorskip("nbformat")
    nb = nbformat.read(path, as_version=4)
    cells = _code_cells(nb)
    assert [c.execution_count for c in cells] == list(range(1, len(cells) + 1)), \
        f"{path.name}: not executed top to bottom in one kernel (scripts/execute_notebooks.py)"
    for i, cell in enumerate(cells):
        sha = hashlib.sha256(cell.source.encode("utf-8")).hexdigest()
        recorded = cell.metadata.get("spgeo", {}).get("source_sha256")
        assert recorded == sha, f"{path.name} code cell {i}: edited after it was executed"
        assert "error" not in _output_kinds(cell), f"{path.name} code cell {i}: an error output"
        for out in cell.get("outputs", []):
            png = out.get("data", {}).get("image/png")
            if png:
                data = base64.b64decode(png)
                width = struct.unpack(">I", data[16:20])[0]      # PNG IHDR
                assert len(data) <= MAX_FIGURE_BYTES and width <= MAX_FIGURE_WIDTH, \
                    f"{path.name} code cell {i}: figure of {len(data)} bytes, {width} px wide"
    assert any(_output_kinds(c) for c in cells), f"{path.name}: committed without outputs"


@pytest.mark.slow   # each notebook runs end to end
@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.stem for p in NOTEBOOKS])
def test_notebook_executes_as_committed(path, tmp_path):
    """A fresh run gives, cell by cell, the same kinds of output (text, figure) as the
    committed one, and no error."""
    nbformat = pytest.importorskip("nbformat")
    nbclient = pytest.importorskip("nbclient")
    committed = nbformat.read(path, as_version=4)
    nb = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                                     resources={"metadata": {"path": str(tmp_path)}})
    client.execute()
    for i, (old, new) in enumerate(zip(_code_cells(committed), _code_cells(nb))):
        assert "error" not in _output_kinds(new), f"{path.name} code cell {i} raised"
        assert _output_kinds(new) == _output_kinds(old), \
            f"{path.name} code cell {i}: outputs differ from the committed ones"
