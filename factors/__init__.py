"""GTSAM factors of spgeo, installed as ``spgeo.factors`` (docs/design.md §4, §6).

Importing this package checks that it belongs to the same tree as the imported ``spgeo``
package (see :func:`assert_same_tree`); ``spgeo.evaluation`` runs the same check.
"""
from pathlib import Path


def assert_same_tree(subpackage: str, init_file: str) -> None:
    """Raise ``ImportError`` if ``spgeo.<subpackage>`` comes from another tree than ``spgeo``.

    With one checkout pip-installed in editable mode and Python started in the root of
    another, ``spgeo`` is imported from the current directory while setuptools' editable
    finder maps ``spgeo.factors`` / ``spgeo.evaluation`` to the installed checkout.

    Args:
        subpackage: ``"factors"`` or ``"evaluation"`` (the top-level folder name in a
            source checkout and the sub-package name once installed).
        init_file: ``__file__`` of that sub-package's ``__init__.py``.

    Accepted locations: ``<spgeo>/<subpackage>`` (a regular install) or the sibling folder
    ``<spgeo>/../<subpackage>`` (a source checkout).
    """
    import spgeo

    here = Path(init_file).resolve().parent
    spgeo_dir = Path(spgeo.__file__).resolve().parent
    if here in (spgeo_dir / subpackage, spgeo_dir.parent / subpackage):
        return
    raise ImportError(
        f"spgeo.{subpackage} was imported from {here} but spgeo from {spgeo_dir}: two "
        f"different spgeo trees are mixed (typically one checkout is pip-installed in "
        f"editable mode and Python runs from the root of another). Install the checkout "
        f"you are in with `pip install -e {spgeo_dir.parent}`, or run Python from a "
        f"directory outside it.")


assert_same_tree("factors", __file__)
