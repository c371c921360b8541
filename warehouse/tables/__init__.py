"""One module per system, each with `TABLES: list[Table]`."""
