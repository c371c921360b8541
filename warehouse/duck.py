"""Read-only SQL over the warehouse through DuckDB.

Each session gets a private, throw-away catalog file holding one view per materialised table, reopened
read-only. Views read the Parquet files directly, so there is no shared DuckDB file to lock: queries work
while a Dagster run is writing (it replaces files atomically), and any write statement is refused by
DuckDB itself.
"""

import shutil
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import duckdb

from warehouse.schemas import TABLES
from warehouse.storage import table_dir, warehouse_root


def _sql_str(s: str | Path) -> str:
    return "'" + str(s).replace("'", "''") + "'"


def materialised_tables() -> dict[str, Path]:
    """Declared tables that have at least one Parquet file, with their folder."""
    found = {}
    for name in TABLES:
        folder = table_dir(name)
        if folder.is_dir() and any(folder.glob("**/data.parquet")):
            found[name] = folder
    return found


def view_sql(name: str, folder: Path) -> str:
    partitioned = not (folder / "data.parquet").exists()
    pattern = folder / ("**/data.parquet" if partitioned else "data.parquet")
    hive = ", hive_partitioning = true" if partitioned else ""
    return f"CREATE VIEW {name} AS SELECT * FROM read_parquet({_sql_str(pattern)}{hive})"


@contextmanager
def connect() -> Iterator[duckdb.DuckDBPyConnection]:
    """A read-only DuckDB connection with every materialised table as a view."""
    tmp = Path(tempfile.mkdtemp(prefix="trafficlearn-sql-"))
    catalog = tmp / "catalog.duckdb"
    try:
        with duckdb.connect(catalog) as con:
            for name, folder in materialised_tables().items():
                con.execute(view_sql(name, folder))
        con = duckdb.connect(catalog, read_only=True)
        # Only the warehouse may be read; nothing may be written anywhere (COPY TO, extensions).
        con.execute(f"SET allowed_directories = [{_sql_str(warehouse_root())}]")
        con.execute("SET enable_external_access = false")
        con.execute("SET lock_configuration = true")
        try:
            yield con
        finally:
            con.close()
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
