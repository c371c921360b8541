"""Markdown tables for Dagster metadata (the UI renders them), shared by every system's reports."""

from collections.abc import Callable

import polars as pl


def _short(v) -> str:
    return f"{v:.3g}" if isinstance(v, float) else ("" if v is None else str(v))


def markdown_table(df: pl.DataFrame, cell: Callable[[object], str] = _short) -> str:
    """One markdown row per DataFrame row; `cell` renders each value (default: floats to 3 significant digits)."""
    head = "| " + " | ".join(df.columns) + " |\n|" + "---|" * len(df.columns) + "\n"
    return head + "".join("| " + " | ".join(cell(v) for v in row) + " |\n" for row in df.iter_rows())
