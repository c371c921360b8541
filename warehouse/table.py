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
