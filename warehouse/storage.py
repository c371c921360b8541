"""Parquet storage: where every table lives, schema enforcement and atomic writes.

Layout under TRAFFICLEARN_HOME (default: `var/` in the checkout):

    warehouse/<table>/data.parquet                 unpartitioned table
    warehouse/<table>/<key>=<value>/data.parquet   partitioned table (the key is not written into the file)

Writes go to a temporary file in the same folder and are renamed into place, so readers (DuckDB views,
a concurrent Dagster run) only ever see a complete file.
"""

import os
import uuid
from collections.abc import Callable
from pathlib import Path

import polars as pl
import pyarrow as pa
import pyarrow.parquet as pq

from warehouse.schemas import TABLES


class SchemaError(ValueError):
    """A frame does not match its table's declared schema."""


def home() -> Path:
    """Root of all generated state; set TRAFFICLEARN_HOME to move it."""
    default = Path(__file__).resolve().parent.parent / "var"
    return Path(os.environ.get("TRAFFICLEARN_HOME", default)).expanduser().resolve()


def warehouse_root() -> Path:
    return home() / "warehouse"


def table_dir(table: str) -> Path:
    return warehouse_root() / table


def table_path(table: str, partition: dict[str, str] | None = None) -> Path:
    folder = table_dir(table)
    for key, value in (partition or {}).items():
        folder = folder / f"{key}={value}"
    return folder / "data.parquet"


def conform(table: str, df: pl.DataFrame) -> pa.Table:
    """Cast `df` to the table's declared schema, or raise SchemaError naming what is wrong."""
    if table not in TABLES:
        raise SchemaError(f"unknown table '{table}'; declared tables: {', '.join(TABLES)}")
    schema = TABLES[table].schema
    missing = [n for n in schema.names if n not in df.columns]
    extra = [n for n in df.columns if n not in schema.names]
    if missing or extra:
        raise SchemaError(f"table '{table}': missing columns {missing}, unexpected columns {extra}")
    for field in schema:
        if not field.nullable and df[field.name].null_count():
            raise SchemaError(f"table '{table}': column '{field.name}' has nulls but is declared non-null")
    try:
        return df.select(schema.names).to_arrow().cast(schema)
    except (pa.ArrowInvalid, pa.ArrowTypeError, pa.ArrowNotImplementedError, ValueError) as e:
        raise SchemaError(f"table '{table}': {e}") from None


def temp_beside(path: Path, suffix: str = "") -> str:
    """A new temp file in `path`'s folder, to be renamed onto `path`, with the permissions a plain open() would
    give (umask applied): mkstemp's 0600 would leave every table, plot and model unreadable to other accounts."""
    tmp = path.parent / f".tmp-{uuid.uuid4().hex}{suffix}"
    os.close(os.open(tmp, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o666))  # the kernel applies the umask
    return str(tmp)


def replace_atomically(path: Path, write: Callable[[str], None], suffix: str = "") -> Path:
    """`write(tmp)` to a new temp file beside `path`, then rename it onto `path`, so readers only ever see a
    complete file; the temp file is removed when anything fails. Returns `path`."""
    tmp = temp_beside(path, suffix)
    try:
        write(tmp)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise
    return path


def write_table(table: str, df: pl.DataFrame, partition: dict[str, str] | None = None) -> Path:
    """Enforce the schema, then write atomically (temp file + rename). Returns the final path."""
    arrow = conform(table, df)
    path = table_path(table, partition)
    path.parent.mkdir(parents=True, exist_ok=True)
    return replace_atomically(path, lambda tmp: pq.write_table(arrow, tmp, compression="zstd"), ".parquet")


def read_table(table: str, partition: dict[str, str] | None = None) -> pl.DataFrame:
    """Read one table (or one partition of it). Raises FileNotFoundError with the asset to materialise, and SchemaError
    when the stored file lacks a declared column (written by an older version: materialise it again)."""
    path = table_path(table, partition)
    if partition is None and not path.exists() and table_dir(table).exists():
        files = sorted(table_dir(table).glob("**/data.parquet"))
        if files:
            return _declared(table, pl.read_parquet([str(f) for f in files], hive_partitioning=True), table_dir(table))
    if not path.exists():
        raise FileNotFoundError(f"table '{table}' has not been materialised yet ({path} is missing)")
    return _declared(table, pl.read_parquet(path), path)


def _declared(table: str, df: pl.DataFrame, where: Path) -> pl.DataFrame:
    missing = [n for n in TABLES[table].schema.names if n not in df.columns] if table in TABLES else []
    if missing:
        raise SchemaError(f"table '{table}' in {where} was written before its declared schema had columns {missing}: "
                          f"materialise '{table}' again")
    return df
