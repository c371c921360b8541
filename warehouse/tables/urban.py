"""Tables of the urban traffic / SUMO (issue 4)."""

import pyarrow as pa  # noqa: F401

from warehouse.table import TS, Table, col  # noqa: F401

TABLES: list[Table] = []
