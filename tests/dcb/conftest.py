"""A small real DCB case: the Swiss ADS-B day's flights first entering the grid 09:00-10:59 UTC."""

import polars as pl
import pytest

from models.dcb.experiment import build_problem


@pytest.fixture(scope="session")
def small_case(swiss_tables):
    sectors, flights, entries = swiss_tables
    first = entries.group_by("flight_id").agg(pl.col("entry_ts").min())
    keep = first.filter(pl.col("entry_ts").dt.hour().is_between(9, 10))["flight_id"].implode()
    return build_problem(entries.filter(pl.col("flight_id").is_in(keep)), sectors, flights.filter(pl.col("flight_id").is_in(keep)), 0.9, 60)
