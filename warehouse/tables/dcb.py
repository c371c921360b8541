"""Tables of the air traffic congestion / DCB (issue 5)."""

import pyarrow as pa  # noqa: F401

from warehouse.table import TS, Table, col  # noqa: F401

TABLES: list[Table] = []
