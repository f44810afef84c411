"""The one HTML table of the result objects' ``_repr_html_`` (what a notebook shows
for a :class:`~spgeo.trajectory.Trajectory` or an :class:`~spgeo.sfm.SfMResult`)."""
from __future__ import annotations

import html
from typing import Iterable, Optional, Sequence

__all__ = ["html_table"]


def html_table(title: str, rows: Iterable[Sequence[object]],
               header: Optional[Sequence[str]] = None) -> str:
    """An HTML ``<table>`` captioned ``title``, one ``<tr>`` per row of ``rows``
    (cells by ``str``, escaped), with a ``header`` row when given."""
    def tr(cells: Sequence[object], tag: str) -> str:
        inner = "".join(f"<{tag} style='text-align:left'>{html.escape(str(c))}</{tag}>"
                        for c in cells)
        return f"<tr>{inner}</tr>"

    head = "" if header is None else tr(header, "th")
    body = "".join(tr(r, "td") for r in rows)
    return (f"<table><caption style='text-align:left'><b>{html.escape(title)}</b></caption>"
            f"{head}{body}</table>")
