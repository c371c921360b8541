"""Shared fixtures: an isolated TRAFFICLEARN_HOME per test and small slices of the bundled real data."""

from pathlib import Path

from models.memory import keep_freed_memory

keep_freed_memory()  # the test process set up as the pipeline's are (pipelines/__init__.py): before polars loads

import polars as pl  # noqa: E402
import pytest  # noqa: E402

REPO = Path(__file__).resolve().parent.parent
OPENSKY = REPO / "data" / "opensky" / "kaliningrad_2022-02-22_2022-03-05.parquet"
SWISS = REPO / "data" / "traffic_samples" / "switzerland_2018-08-01.parquet"


@pytest.fixture(autouse=True)
def isolated_home(tmp_path, monkeypatch) -> Path:
    home = tmp_path / "home"
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(home))
    return home


@pytest.fixture(scope="session")
def opensky_raw() -> pl.DataFrame:
    return pl.read_parquet(OPENSKY)


@pytest.fixture(scope="session")
def opensky_small(opensky_raw, tmp_path_factory) -> Path:
    """Real state vectors of six flights (three per route, before and after 2022-02-27)."""
    day = pl.col("time").dt.date().alias("day")
    keep = (
        opensky_raw.group_by("icao24", "callsign", day)
        .agg(pl.col("time").min())
        .sort("time")
        .with_columns(route=pl.col("callsign").str.slice(0, 3))
        .group_by("route", maintain_order=True)
        .agg(pl.col("icao24", "callsign", "day").gather([0, 1, -1]))
        .explode("icao24", "callsign", "day")
    )
    df = opensky_raw.with_columns(day).join(keep.select("icao24", "callsign", "day"), on=["icao24", "callsign", "day"]).drop("day")
    path = tmp_path_factory.mktemp("data") / "six_flights.parquet"
    df.write_parquet(path)
    return path


@pytest.fixture(scope="session")
def swiss_tables():
    """The bundled Swiss day through the DCB demand and the default grid: (sectors, flights, entries)."""
    from models.dcb.airspace import GridSectorisation  # here, not at the top: only the DCB tests and bench need it
    from models.dcb.experiment import airspace_tables, load_demand

    points, flights, _, _ = load_demand(SWISS)
    return airspace_tables(points, flights, GridSectorisation())
