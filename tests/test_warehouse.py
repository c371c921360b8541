"""Storage layer and read-only SQL: schema enforcement, atomic writes, views, refusal of writes, CLI."""

import subprocess
import sys
from pathlib import Path

import polars as pl
import pytest

from warehouse import storage
from warehouse.__main__ import main
from warehouse.duck import connect
from warehouse.schemas import TABLES, data_dictionary_markdown

REPO = Path(__file__).resolve().parent.parent


def _summary(n: int = 3) -> pl.DataFrame:
    return pl.DataFrame({"source": ["f"] * n, "outcome": ["read"] * n, "reason": [""] * n, "rows": list(range(n))})


def test_write_enforces_declared_schema():
    with pytest.raises(storage.SchemaError, match="missing columns \\['rows'\\]"):
        storage.write_table("ingest_summary", _summary().drop("rows"))
    with pytest.raises(storage.SchemaError, match="unexpected columns \\['extra'\\]"):
        storage.write_table("ingest_summary", _summary().with_columns(extra=pl.lit(1)))
    with pytest.raises(storage.SchemaError, match="declared non-null"):
        storage.write_table("ingest_summary", _summary().with_columns(rows=pl.lit(None, dtype=pl.Int64)))
    with pytest.raises(storage.SchemaError, match="unknown table"):
        storage.write_table("nope", _summary())
    path = storage.write_table("ingest_summary", _summary().with_columns(pl.col("rows").cast(pl.Int32)))
    assert pl.read_parquet(path).schema["rows"] == pl.Int64


def test_reading_a_table_written_before_a_column_was_declared_says_to_materialise_it_again():
    path = storage.write_table("ingest_summary", _summary())
    _summary().drop("rows").write_parquet(path)  # as an older version of the code would have written it
    with pytest.raises(storage.SchemaError, match=r"table 'ingest_summary' in .* declared schema had columns \['rows'\]: materialise 'ingest_summary' again"):
        storage.read_table("ingest_summary")
    _summary().with_columns(extra=pl.lit(1)).write_parquet(path)  # a column no longer declared is no obstacle to reading
    assert storage.read_table("ingest_summary").height == 3


def test_atomic_write_leaves_old_file_on_failure(monkeypatch):
    path = storage.write_table("ingest_summary", _summary(3))

    def crash(*a, **k):
        raise OSError("disk full")

    monkeypatch.setattr(storage.pq, "write_table", crash)  # a crash mid-write: a fault we cannot cause for real
    with pytest.raises(OSError):
        storage.write_table("ingest_summary", _summary(5))
    assert pl.read_parquet(path).height == 3
    assert [p.name for p in path.parent.iterdir()] == ["data.parquet"]


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_written_files_follow_the_umask(umask, mode):
    """Not mkstemp's 0600: others may read the warehouse, plots and recordings as the umask allows."""
    import os

    from warehouse.artifacts import save_plot

    old = os.umask(umask)
    try:
        paths = [storage.write_table("ingest_summary", _summary()), save_plot("p", b"png")[0]]
    finally:
        os.umask(old)
    assert [oct(p.stat().st_mode & 0o777) for p in paths] == [oct(mode)] * 2


def test_partitioned_table_view():
    storage.write_table("ingest_summary", _summary(2), partition={"partition": "a"})
    storage.write_table("ingest_summary", _summary(3), partition={"partition": "b"})
    with connect() as con:
        rows = con.sql("SELECT partition, count(*) FROM ingest_summary GROUP BY ALL ORDER BY 1").fetchall()
    assert rows == [("a", 2), ("b", 3)]
    file_cols = pl.read_parquet(storage.table_path("ingest_summary", {"partition": "a"})).columns
    assert "partition" not in file_cols  # the hive key lives in the path only


def test_sql_is_read_only(tmp_path):
    storage.write_table("ingest_summary", _summary())
    with connect() as con:
        assert con.sql("SELECT sum(rows) FROM ingest_summary").fetchall()[0][0] == 3
        for stmt in [
            "CREATE TABLE x AS SELECT 1",
            "DROP VIEW ingest_summary",
            f"COPY (SELECT 1) TO '{tmp_path / 'out.csv'}'",
            "INSERT INTO ingest_summary VALUES ('a','b','c',1)",
        ]:
            with pytest.raises(Exception):
                con.sql(stmt)
    assert not (tmp_path / "out.csv").exists()


def test_cli_tables_sql_formats(capsys):
    storage.write_table("ingest_summary", _summary())
    assert main(["tables"]) == 0
    assert "ingest_summary" in capsys.readouterr().out
    assert main(["sql", "SELECT outcome, rows FROM ingest_summary ORDER BY rows", "--format", "csv"]) == 0
    assert capsys.readouterr().out.splitlines() == ["outcome,rows", "read,0", "read,1", "read,2"]
    assert main(["sql", "SELECT count(*) AS n FROM ingest_summary", "--format", "json"]) == 0
    assert '"n": 3' in capsys.readouterr().out
    assert main(["sql", "DELETE FROM ingest_summary"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error:") and len(err.strip().splitlines()) == 1
    for query, n in (("", 0), ("SELECT 1; SELECT 2", 2)):
        assert main(["sql", query]) == 1
        assert capsys.readouterr().err.strip() == f"error: expected one SQL statement, got {n}" + (" (several: python -m warehouse shell)" if n else "")
    # an error DuckDB only raises while fetching rows, not while planning
    assert main(["sql", "SELECT CAST(outcome AS INTEGER) FROM ingest_summary"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: Conversion Error") and len(err.strip().splitlines()) == 1
    # a table not materialised (yet): the error names the ones there are
    assert main(["sql", "SELECT * FROM flights"]) == 1
    err = capsys.readouterr().err
    assert err.startswith("error: Catalog Error") and err.strip().endswith("(tables: ingest_summary)") and len(err.strip().splitlines()) == 1
    assert main(["sql", "SELECT no_such_function(1)"]) == 1  # a catalog error too, but no table's: no list of tables
    err = capsys.readouterr().err
    assert err.startswith("error: Catalog Error: Scalar Function") and "tables:" not in err


def test_cli_shell_piped(monkeypatch, capsys):
    storage.write_table("ingest_summary", _summary())
    script = "SELECT count(*) AS n\nFROM ingest_summary;\nDROP VIEW ingest_summary;\nSELECT sum(rows) AS total FROM ingest_summary\n"
    monkeypatch.setattr(sys, "stdin", __import__("io").StringIO(script))
    assert main(["shell"]) == 0
    out = capsys.readouterr().out
    assert "(1 row)" in out and "error: Invalid Input Error" in out
    # the last statement has no ';' but ends the input: it still runs
    assert out.split("total")[-1].split()[1] == "3"


def test_cli_reads_while_a_writer_replaces_files(isolated_home):
    """Readers never see a half-written file nor a lock error while a writer keeps replacing the table."""
    storage.write_table("ingest_summary", _summary(1000))
    writer = subprocess.Popen(
        [sys.executable, "-c",
         "import polars as pl; from warehouse.storage import write_table\n"
         "for i in range(40): write_table('ingest_summary', pl.DataFrame({'source':['f']*1000,'outcome':['read']*1000,'reason':['']*1000,'rows':list(range(1000))}))"],
        cwd=REPO, env={**__import__("os").environ, "TRAFFICLEARN_HOME": str(isolated_home)},
    )
    counts = []
    while writer.poll() is None:
        with connect() as con:
            counts.append(con.sql("SELECT count(*) FROM ingest_summary").fetchall()[0][0])
    assert writer.returncode == 0
    assert counts and set(counts) == {1000}


def test_cli_output_piped_into_head_ends_quietly(isolated_home):
    """`python -m warehouse sql ... | head -1`: the reader closing the pipe early gives no traceback."""
    storage.write_table("ingest_summary", _summary(100_000))  # output far beyond a pipe's buffer
    cli = subprocess.Popen([sys.executable, "-m", "warehouse", "sql", "SELECT * FROM ingest_summary", "--format", "csv"],
                           cwd=REPO, env={**__import__("os").environ, "TRAFFICLEARN_HOME": str(isolated_home)},
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert cli.stdout.readline() == b"source,outcome,reason,rows\n"
    cli.stdout.close()  # as head does after its lines
    err = cli.stderr.read().decode()
    assert cli.wait() == 1 and err == ""


def test_data_dictionary_in_readme():
    readme = (REPO / "README.md").read_text()
    assert data_dictionary_markdown() in readme, "README data dictionary is stale: python -m warehouse schema --markdown"
    for name in TABLES:
        assert f"`{name}`" in readme


def test_shell_survives_an_interrupted_query(capsys):
    """Ctrl-C during a long query ends the query, not the shell. DuckDB then raises RuntimeError("Query interrupted")
    (measured with a real SIGINT; a test sending one races the query's own interrupt checks, so it is stood in for)."""
    import duckdb

    from warehouse.__main__ import _shell_run

    class InterruptedQuery:
        def sql(self, _statement):
            raise RuntimeError("Query interrupted")

    _shell_run(InterruptedQuery(), "SELECT count(*) FROM range(100000000000) a;")
    assert capsys.readouterr().out.strip() == "error: Query interrupted"
    _shell_run(duckdb.connect(), "SELECT 3 AS y;")
    assert "3" in capsys.readouterr().out
