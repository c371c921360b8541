"""Checks every system's tables share: the file on disk has exactly the declared schema."""

import dagster as dg
import pyarrow.parquet as pq

from warehouse.schemas import TABLES
from warehouse.storage import table_path


def schema_check(table: str) -> dg.AssetChecksDefinition:
    @dg.asset_check(asset=table, name="schema_matches_declaration", description=f"{table} has exactly its declared schema")
    def check() -> dg.AssetCheckResult:
        found = pq.read_schema(table_path(table))
        declared = TABLES[table].schema
        diffs = [
            f"{f.name}: {found.field(f.name).type if f.name in found.names else 'missing'} != {f.type}"
            for f in declared
            if f.name not in found.names or found.field(f.name).type != f.type
        ]
        return dg.AssetCheckResult(passed=not diffs and found.names == declared.names, metadata={"differences": dg.MetadataValue.json(diffs)})

    return check


def schema_checks(tables) -> list[dg.AssetChecksDefinition]:
    return [schema_check(t) for t in tables]
