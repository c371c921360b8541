"""The output of a paired-comparisons asset (urban_comparisons, dcb_comparisons): the table, its markdown, and a warning
when one seed makes every comparison a difference rather than a test."""

import dagster as dg
import polars as pl

from models.markdown import markdown_table


def comparisons_output(context: dg.AssetExecutionContext, df: pl.DataFrame) -> dg.Output:
    if not df.is_empty() and df["seeds"].max() < 2:
        context.log.warning("one training seed: the comparisons are differences, not tests (p = 1); train more `seeds` for a test")
    return dg.Output(df, metadata={"comparisons": dg.MetadataValue.md(markdown_table(df))})
