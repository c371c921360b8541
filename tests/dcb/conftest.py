"""A small real DCB case: the Swiss ADS-B day's flights first entering the grid 09:00-10:59 UTC."""

from pathlib import Path

import polars as pl
import pytest

from models.dcb.airspace import GridSectorisation
from models.dcb.experiment import airspace_tables, build_problem, load_demand

SWISS = Path(__file__).resolve().parents[2] / "data" / "traffic_samples" / "switzerland_2018-08-01.parquet"


@pytest.fixture(scope="session")
def swiss_tables():
    points, flights, _, _ = load_demand(SWISS)
    return airspace_tables(points, flights, GridSectorisation())


@pytest.fixture(scope="session")
def small_case(swiss_tables):
    sectors, flights, entries = swiss_tables
    first = entries.group_by("flight_id").agg(pl.col("entry_ts").min())
    keep = first.filter(pl.col("entry_ts").dt.hour().is_between(9, 10))["flight_id"].implode()
    return build_problem(entries.filter(pl.col("flight_id").is_in(keep)), sectors, flights.filter(pl.col("flight_id").is_in(keep)), 0.9, 60)
