"""Every warehouse table's schema, declared once.

The IO manager enforces these on write, the DuckDB layer exposes one view per table, and the README's
data dictionary is generated from the same declarations (`python -m warehouse schema --markdown`).
Units live in the column name where they could be ambiguous (alt_m, speed_mps) and in `unit` always.
"""

from warehouse.table import Column, Table
from warehouse.tables import applearn, aviation, dcb, trajectory, urban

SYSTEMS = {"aviation": aviation, "trajectory": trajectory, "applearn": applearn, "urban": urban, "dcb": dcb}

TABLES: dict[str, Table] = {t.name: t for module in SYSTEMS.values() for t in module.TABLES}

__all__ = ["Column", "Table", "TABLES", "SYSTEMS", "data_dictionary_markdown"]


def data_dictionary_markdown() -> str:
    """The README's data dictionary: one section per table, one row per column."""
    parts = []
    for t in TABLES.values():
        parts.append(f"#### `{t.name}`\n\n{t.description}\n\n| column | type | unit | description |\n|---|---|---|---|")
        for c in t.columns:
            parts.append(f"| `{c.name}` | {c.type} | {c.unit} | {c.description} |")
        parts.append("")
    return "\n".join(parts)
