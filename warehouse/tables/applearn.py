"""Tables of AppLearn inverse RL and its SVM behavioural-cloning baseline (chapter 6, part of issue 3)."""

import pyarrow as pa  # noqa: F401

from warehouse.table import TS, Table, col  # noqa: F401

TABLES: list[Table] = []
