"""Command line over the warehouse.

    python -m warehouse tables                       every materialised table with its row count
    python -m warehouse sql "SELECT ..." [--format table|csv|json]
    python -m warehouse shell                        interactive DuckDB session, views loaded
    python -m warehouse schema [--markdown]          declared tables and columns (the data dictionary)
"""

import argparse
import csv
import io
import json
import os
import sys

import duckdb

from warehouse.duck import connect
from warehouse.schemas import TABLES, data_dictionary_markdown


def _render(rel: duckdb.DuckDBPyRelation, fmt: str) -> str:
    columns = rel.columns
    rows = rel.fetchall()
    if fmt == "json":
        return json.dumps([dict(zip(columns, r)) for r in rows], default=str, indent=1)
    if fmt == "csv":
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerow(columns)
        writer.writerows(rows)
        return buf.getvalue().rstrip("\n")
    cells = [[str(c) for c in columns]] + [["" if v is None else str(v) for v in r] for r in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(columns))]
    lines = ["  ".join(v.ljust(w) for v, w in zip(row, widths)).rstrip() for row in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    lines.append(f"({len(rows)} row{'s' if len(rows) != 1 else ''})")
    return "\n".join(lines)


def _table_names(con: duckdb.DuckDBPyConnection) -> list[str]:
    """The materialised tables: the session's views (warehouse.duck)."""
    return [r[0] for r in con.sql("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()]


def _catalog_hint(con: duckdb.DuckDBPyConnection, error: duckdb.Error) -> str:
    """For an unknown table: which tables there are (a table appears once its asset has been materialised)."""
    if not isinstance(error, duckdb.CatalogException) or "Table with name" not in str(error):  # not an unknown function or setting
        return ""
    names = _table_names(con)
    return f" (tables: {', '.join(sorted(names))})" if names else " (no tables materialised yet: run `make demo`)"


def cmd_tables(args) -> int:
    with connect() as con:
        names = _table_names(con)
        if not names:
            print("no tables materialised yet: run `make demo` or materialise assets with dagster")
            return 0
        union = " UNION ALL ".join(f"SELECT '{n}' AS \"table\", count(*) AS \"rows\" FROM {n}" for n in sorted(names))
        print(_render(con.sql(union), args.format))
    return 0


def cmd_sql(args) -> int:
    with connect() as con:
        try:
            n = len(con.extract_statements(args.query))
            if n != 1:  # DuckDB would run them all and show the last result only
                print(f"error: expected one SQL statement, got {n}" + (" (several: python -m warehouse shell)" if n > 1 else ""), file=sys.stderr)
                return 1
            rel = con.sql(args.query)
            # DuckDB runs a SELECT lazily: conversion and other run-time errors come at fetch time.
            text = None if rel is None else _render(rel, args.format)
        except duckdb.Error as e:
            print(f"error: {str(e).splitlines()[0]}{_catalog_hint(con, e)}", file=sys.stderr)
            return 1
        if text is not None:  # None: a statement with no result set; DuckDB already refused anything that writes
            print(text)
    return 0


def cmd_shell(args) -> int:
    with connect() as con:
        names = _table_names(con)
        print(f"trafficlearn warehouse (read-only): {', '.join(sorted(names)) or 'no tables yet'}")
        print("End each statement with ';'. Ctrl-D to quit.")
        buffer = ""
        while True:
            try:
                line = input("sql> " if not buffer else "...> ")
            except EOFError:
                print()
                if buffer.strip():  # piped input whose last statement lacks its ';'
                    _shell_run(con, buffer)
                return 0
            except KeyboardInterrupt:  # Ctrl-C abandons what was typed, as in a shell; Ctrl-D quits
                print()
                buffer = ""
                continue
            buffer += line + "\n"
            if not buffer.strip().endswith(";"):
                continue
            _shell_run(con, buffer)
            buffer = ""


def _shell_run(con: duckdb.DuckDBPyConnection, statement: str) -> None:
    try:
        rel = con.sql(statement)
        if rel is not None:
            print(_render(rel, "table"))
    except (duckdb.Error, RuntimeError) as e:  # RuntimeError "Query interrupted": Ctrl-C stops the query, not the shell
        print(f"error: {str(e).splitlines()[0]}")


def cmd_schema(args) -> int:
    if args.markdown:
        print(data_dictionary_markdown())
        return 0
    for t in TABLES.values():
        print(f"{t.name}: " + ", ".join(f"{c.name} {c.type}" for c in t.columns))
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m warehouse", description="Read-only SQL over trafficlearn's tables.")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("tables", help="every materialised table with its row count")
    p.add_argument("--format", choices=["table", "csv", "json"], default="table")
    p.set_defaults(func=cmd_tables)
    p = sub.add_parser("sql", help="run one read-only query")
    p.add_argument("query")
    p.add_argument("--format", choices=["table", "csv", "json"], default="table")
    p.set_defaults(func=cmd_sql)
    sub.add_parser("shell", help="interactive DuckDB session with the views loaded").set_defaults(func=cmd_shell)
    p = sub.add_parser("schema", help="declared tables and columns")
    p.add_argument("--markdown", action="store_true", help="print the README data dictionary")
    p.set_defaults(func=cmd_schema)
    args = parser.parse_args(argv)
    try:
        return args.func(args)
    except BrokenPipeError:  # `... | head` stopped reading: no traceback, and none from Python's flush at exit either
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 1


if __name__ == "__main__":
    sys.exit(main())
