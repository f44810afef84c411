"""The one table formatter of the evaluation protocols (spgeo.evaluation.tables)."""
import numpy as np
import pytest

from spgeo.evaluation.tables import MISSING, cell, markdown_row, markdown_table


def test_cell_missing_numbers_text_and_ints():
    assert [cell(v) for v in (None, float("nan"), float("inf"), -np.inf)] == [MISSING] * 4
    assert MISSING == "-"
    assert cell(0.12345) == "0.12" and cell(0.12345, 3) == "0.123" and cell(2.5, 0) == "2"
    assert cell(np.float32(0.5), 1) == "0.5" and cell(np.float64(np.nan), 1) == "-"
    assert cell(3) == "3" and cell(np.int64(4), 3) == "4"         # integers stay integers
    assert cell(True) == "True" and cell("x|y") == "x|y" and cell("") == ""


def test_cell_format_template():
    assert cell(0.01234, "{:.3g}") == "0.0123"
    assert cell(-0.4, "{:+.0f} %") == "-0 %" and cell(40.2, "{:+.0f} %") == "+40 %"
    assert cell(30.0, "{:g}") == "30" and cell(5, "{}") == "5" and cell(5, "{:.1f}") == "5.0"
    assert cell(float("nan"), "{:.0f} %") == MISSING


def test_markdown_row_escapes_and_formats():
    assert markdown_row(["a", 1, 0.5, None]) == "| a | 1 | 0.50 | - |"
    assert markdown_row(["x | y", "line\nbreak", ""]) == "| x / y | line break | |"


def test_markdown_table_alignment_and_checks():
    assert markdown_table(["name", "value"], [["a", 1.0]], "lr") == [
        "| name | value |", "|---|---:|", "| a | 1.00 |"]
    assert markdown_table(["a", "b"], [])[1] == "|---|---|"
    with pytest.raises(ValueError, match="align"):
        markdown_table(["a", "b"], [], "l")
    with pytest.raises(ValueError, match="align"):
        markdown_table(["a"], [], "c")
    with pytest.raises(ValueError, match="1 cells under 2 columns"):
        markdown_table(["a", "b"], [["x"]])
