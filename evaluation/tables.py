"""The one table formatter of the evaluation protocols.

* :func:`cell`: one value's text (a number with its decimals or a format, ``-``
  for a missing or non-finite value).
* :func:`markdown_row` / :func:`markdown_table`: Markdown table lines from a
  header and rows of cells.

Every protocol's table (:class:`~spgeo.evaluation.jobs.EvalTable` and the
hand-laid tables of the protocols' result types) writes its cells and lines
through these, so a missing number reads the same (``-``) everywhere.
"""
from __future__ import annotations

import math
import numbers
from typing import Iterable, List, Sequence, Union

__all__ = ["MISSING", "cell", "markdown_row", "markdown_table"]

#: The text of a missing value: None, NaN, +-inf.
MISSING = "-"


def cell(value: object, fmt: Union[int, str] = 2) -> str:
    """The text of one table cell.

    * None, NaN and +-inf: :data:`MISSING` (``-``).
    * Anything that is not a real number (text, bools, other objects): ``str(value)``.
    * ``fmt`` an int (decimals): an integer as an integer (``3``), any other real
      number with ``fmt`` decimals (``cell(0.1234, 3) == "0.123"``).
    * ``fmt`` a :meth:`str.format` template with one field (``"{:.3g}"``,
      ``"{:+.0f} %"``, ``"{}"``): the number through the template.

    numpy scalars are numbers like Python's.
    """
    if value is None:
        return MISSING
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        return str(value)
    if not math.isfinite(value):
        return MISSING
    if isinstance(fmt, str):
        return fmt.format(value)
    if isinstance(value, numbers.Integral):
        return str(int(value))
    return f"{float(value):.{int(fmt)}f}"


def markdown_row(cells: Sequence[object]) -> str:
    """One Markdown table line ``| a | b |``: a text cell as it is, any other value
    through :func:`cell` (2 decimals); a ``|`` in a cell becomes ``/`` and a line
    break a space (the line stays one row); an empty cell is ``| |``."""
    texts = [c if isinstance(c, str) else cell(c) for c in cells]
    texts = [t.replace("|", "/").replace("\n", " ") for t in texts]
    return "|" + "|".join(f" {t} " if t else " " for t in texts) + "|"


def markdown_table(header: Sequence[str], rows: Iterable[Sequence[object]],
                   align: str = "") -> List[str]:
    """The lines of a Markdown table: the header (:func:`markdown_row`), the
    separator and one :func:`markdown_row` per row.

    ``align``: ``""`` (every column ``---``) or one letter per column, ``l``
    (``---``) or ``r`` (``---:``, right-aligned numbers).  Raises ``ValueError``
    for another ``align`` or a row whose length is not the header's.
    """
    if align and (len(align) != len(header) or set(align) - {"l", "r"}):
        raise ValueError(f"markdown_table: align {align!r} must be one 'l' or 'r' per column "
                         f"({len(header)} columns)")
    lines = [markdown_row(header),
             "|" + "".join("---:|" if a == "r" else "---|" for a in (align or "l" * len(header)))]
    for row in rows:
        if len(row) != len(header):
            raise ValueError(f"markdown_table: a row of {len(row)} cells under {len(header)} "
                             f"columns: {list(row)!r}")
        lines.append(markdown_row(row))
    return lines
