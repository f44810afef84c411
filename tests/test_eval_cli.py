"""``spgeo eval`` names (spgeo.cli.eval.PROTOCOLS) against the modules of evaluation/."""
from __future__ import annotations

import re
from pathlib import Path

from spgeo.cli.eval import PROTOCOLS, protocols

ROOT = Path(__file__).resolve().parents[1]


def test_every_module_with_main_is_a_protocol():
    """Each module of evaluation/ with a top-level ``main(`` has exactly one name, and
    every name points at such a module."""
    with_main = {".".join(p.relative_to(ROOT / "evaluation").with_suffix("").parts)
                 for p in (ROOT / "evaluation").rglob("*.py")
                 if re.search(r"^def main\(", p.read_text(encoding="utf-8"), re.M)}
    assert sorted(PROTOCOLS.values()) == sorted(with_main)
    assert sorted(protocols()) == sorted(PROTOCOLS)


def test_every_evaluation_folder_is_a_package():
    """setup.py installs evaluation/'s sub-packages with find_packages: each folder
    holding modules needs an ``__init__.py``."""
    folders = {p.parent for p in (ROOT / "evaluation").rglob("*.py")
               if "__pycache__" not in p.parts}
    assert all((f / "__init__.py").is_file() for f in folders)
