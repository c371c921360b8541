"""A figure in an asset's metadata: the PNG under plots/ (its path) and embedded as markdown, shown in the Dagster UI."""

import dagster as dg

from warehouse.artifacts import save_plot


def add_plot(metadata: dict, name: str, png: bytes) -> None:
    path, md = save_plot(name, png)
    metadata[name] = dg.MetadataValue.md(md)
    metadata[f"{name}_png"] = dg.MetadataValue.path(str(path))
