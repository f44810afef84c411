"""Importing ``spgeo.factors`` / ``spgeo.evaluation`` from another tree than ``spgeo`` fails clearly.

The subprocesses emulate setuptools' editable finder (a meta-path finder that maps
``spgeo.factors`` and ``spgeo.evaluation`` to this checkout's top-level folders), so the
tests do not depend on how spgeo was installed.
"""
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]

FINDER = f"""
import sys
from importlib.util import spec_from_file_location

class EditableFinder:
    mapping = {{"spgeo.factors": {str(ROOT / "factors")!r},
               "spgeo.evaluation": {str(ROOT / "evaluation")!r}}}

    @classmethod
    def find_spec(cls, fullname, path=None, target=None):
        folder = cls.mapping.get(fullname)
        if folder is None:
            return None
        return spec_from_file_location(fullname, folder + "/__init__.py",
                                       submodule_search_locations=[folder])

sys.meta_path.append(EditableFinder)
"""


def _run(code: str, cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", FINDER + code], cwd=cwd, capture_output=True,
                          text=True, timeout=120)


@pytest.fixture(scope="module")
def other_tree(tmp_path_factory) -> Path:
    """A second tree holding a copy of ``spgeo/`` only (no ``factors/``, ``evaluation/``)."""
    root = tmp_path_factory.mktemp("other_checkout")
    shutil.copytree(ROOT / "spgeo", root / "spgeo",
                    ignore=shutil.ignore_patterns("data", "__pycache__"))
    return root


@pytest.mark.parametrize("sub", ["factors", "evaluation"])
def test_mixed_trees_raise_a_clear_import_error(other_tree, sub):
    proc = _run(f"import spgeo, spgeo.{sub}", cwd=other_tree)
    assert proc.returncode != 0
    # ``spgeo.evaluation`` imports ``spgeo.factors`` first, which reports the same mix-up
    assert "ImportError: spgeo." in proc.stderr, proc.stderr
    assert "two different spgeo trees are mixed" in proc.stderr
    assert str((other_tree / "spgeo").resolve()) in proc.stderr
    assert str(ROOT) in proc.stderr
    assert "pip install -e" in proc.stderr


def test_same_tree_imports(tmp_path):
    proc = _run("import spgeo, spgeo.factors, spgeo.evaluation; "
                "print(spgeo.__file__, spgeo.factors.__file__, spgeo.evaluation.__file__)",
                cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    spgeo_file, factors_file, evaluation_file = proc.stdout.split()
    assert Path(spgeo_file).parent.parent == Path(factors_file).parent.parent \
        == Path(evaluation_file).parent.parent
