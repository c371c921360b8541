"""Dagster IO manager: every asset output is a warehouse table (Parquet), schema-enforced on write.

Like PUDL's Parquet IO manager it holds no data logic: the asset key's last element names the table,
the declared schema is enforced by `warehouse.storage`, and row count, path and size are recorded as
metadata. Partitioned assets write one file per partition key.
"""

import dagster as dg
import polars as pl

from warehouse.storage import read_table, write_table


def _partition(context) -> dict[str, str] | None:
    if not context.has_asset_partitions:
        return None
    return {"partition": context.asset_partition_key}


class ParquetIOManager(dg.ConfigurableIOManager):
    def handle_output(self, context: dg.OutputContext, obj: pl.DataFrame) -> None:
        table = context.asset_key.path[-1]
        path = write_table(table, obj, _partition(context))
        context.add_output_metadata(
            {
                "rows": dg.MetadataValue.int(obj.height),
                "path": dg.MetadataValue.path(str(path)),
                "size_bytes": dg.MetadataValue.int(path.stat().st_size),
                "dagster/row_count": dg.MetadataValue.int(obj.height),
            }
        )

    def load_input(self, context: dg.InputContext) -> pl.DataFrame:
        table = context.upstream_output.asset_key.path[-1] if context.upstream_output else context.asset_key.path[-1]
        return read_table(table, _partition(context))
