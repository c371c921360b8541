"""Building blocks of a table declaration: columns with unit and description, a table with its pyarrow schema.

Each system declares its tables in `warehouse/tables/<system>.py`; `warehouse.schemas` gathers them.
"""

from dataclasses import dataclass

import pyarrow as pa

TS = pa.timestamp("us", tz="UTC")


@dataclass(frozen=True)
class Column:
    name: str
    type: pa.DataType
    unit: str
    description: str
    nullable: bool = False


@dataclass(frozen=True)
class Table:
    name: str
    description: str
    columns: tuple[Column, ...]

    @property
    def schema(self) -> pa.Schema:
        return pa.schema(
            [pa.field(c.name, c.type, nullable=c.nullable) for c in self.columns],
            metadata={"table": self.name, "description": self.description},
        )


def col(name, type_, unit, description, nullable=False) -> Column:
    return Column(name, type_, unit, description, nullable)


def comparison_columns(methods: str, references: str, metrics: str, seeds_note: str = "") -> tuple[Column, ...]:
    """The columns of models.stats.paired_comparisons (after the group column): which method against which, per metric;
    `seeds_note` ends the description of `seeds` (what one seed's value is)."""
    return (
        col("method", pa.string(), "", f"the compared method: {methods}"),
        col("reference", pa.string(), "", f"the method it is compared with: {references}"),
        col("metric", pa.string(), "", metrics),
        col("seeds", pa.int64(), "", f"training seeds both methods ran (the pairs){seeds_note}"),
        col("method_mean", pa.float64(), "metric's", "the method's metric, mean over the seeds"),
        col("reference_mean", pa.float64(), "metric's", "the reference's metric, mean over the seeds"),
        col("mean_diff", pa.float64(), "metric's", "mean over seeds of (method - reference)"),
        col("std_diff", pa.float64(), "metric's", "std (ddof 1) over seeds of the same; null for one seed", nullable=True),
        col("seeds_higher", pa.int64(), "", "seeds where the method's metric is higher than the reference's"),
        col("seeds_lower", pa.int64(), "", "seeds where it is lower"),
        col("p_two_sided", pa.float64(), "", "exact sign-flip test of mean_diff over the seeds (a seeded Monte Carlo estimate "
            "beyond 20 seeds); 1 for a single seed"),
    )
