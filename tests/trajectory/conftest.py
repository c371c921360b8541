"""The foundation's tables built once per session from the bundled real data, for every trajectory test."""

from pathlib import Path

import polars as pl
import pytest

REPO = Path(__file__).resolve().parents[2]
OPENSKY = REPO / "data" / "opensky" / "kaliningrad_2022-02-22_2022-03-05.parquet"
GFS = REPO / "data" / "weather" / "gfs_2011_isobaric_t_u_v.grib2"


@pytest.fixture(scope="session")
def aviation_tables():
    """ingest -> 20 s tracks + weather -> phases -> modes -> split: (tracks_20s, trajectory_modes, flights, flight_splits, weather)."""
    from models.aviation.airports import flights_table
    from models.aviation.ingest import ingest
    from models.aviation.modes import trajectory_modes
    from models.aviation.phases import assign_phases
    from models.aviation.resample import resample
    from models.aviation.split import split_flights
    from models.aviation.weather import read_weather, sample_weather

    tracks, _, _ = ingest(OPENSKY)
    flights = flights_table(tracks)
    weather = read_weather(GFS)
    grid = resample(tracks)
    met = sample_weather(weather, grid["ts"], grid["lat"].to_numpy(), grid["lon"].to_numpy(), grid["alt_m"].to_numpy(), alignment="time_of_day")
    tracks20 = assign_phases(grid.with_columns(**{k: pl.Series(v) for k, v in met.items()}), flights)
    modes, _ = trajectory_modes(tracks20, flights)
    return tracks20, modes, flights, split_flights(flights, modes), weather
