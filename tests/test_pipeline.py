"""The real Dagster pipeline end to end on real data: assets, checks, metadata, SQL over the result."""

import pytest

from pipelines.definitions import defs
from warehouse.duck import connect
from warehouse.schemas import TABLES

TABLES_BUILT = ["flight_tracks", "flights", "ingest_rejects", "ingest_summary", "weather",
                "tracks_20s", "flight_phases", "trajectory_modes", "flight_splits"]


@pytest.fixture(scope="module")
def run(opensky_small, tmp_path_factory):
    import os

    home = tmp_path_factory.mktemp("pipeline_home")
    old = os.environ.get("TRAFFICLEARN_HOME")
    os.environ["TRAFFICLEARN_HOME"] = str(home)
    try:
        job = defs.resolve_job_def("aviation_data")
        result = job.execute_in_process(
            run_config={"ops": {"flight_ingest": {"config": {"source_path": str(opensky_small)}}}}
        )
        yield result, home
    finally:
        if old is None:
            os.environ.pop("TRAFFICLEARN_HOME", None)
        else:
            os.environ["TRAFFICLEARN_HOME"] = old


@pytest.fixture
def in_home(run, monkeypatch):
    monkeypatch.setenv("TRAFFICLEARN_HOME", str(run[1]))


def test_run_succeeds_and_every_check_passes(run):
    result, _ = run
    assert result.success
    evals = result.get_asset_check_evaluations()
    assert len(evals) >= len(TABLES_BUILT) + 6
    import dagster as dg

    failed = [(e.asset_key.to_user_string(), e.check_name) for e in evals if not e.passed and e.severity == dg.AssetCheckSeverity.ERROR]
    assert failed == []
    # the min-flights-per-mode check is a warning; its verdict must agree with what it measured
    (warn,) = [e for e in evals if e.severity == dg.AssetCheckSeverity.WARN]
    assert warn.check_name == "modes_min_flights"
    assert warn.passed == (warn.metadata["modes_below_2"].value == [])
    assert warn.metadata["smallest_mode"].value >= 1


def test_tables_queryable_and_consistent(in_home):
    with connect() as con:
        views = {r[0] for r in con.sql("SELECT view_name FROM duckdb_views() WHERE NOT internal").fetchall()}
        assert set(TABLES_BUILT) <= views
        for t in TABLES_BUILT:
            assert con.sql(f"SELECT * FROM {t} LIMIT 0").columns == [c.name for c in TABLES[t].columns]
        n_flights = con.sql("SELECT count(*) FROM flights").fetchall()[0][0]
        assert n_flights == 6
        read, accounted = con.sql(
            "SELECT sum(rows) FILTER (outcome = 'read'), sum(rows) FILTER (outcome <> 'read') FROM ingest_summary"
        ).fetchall()[0]
        assert read == accounted
        assert con.sql("SELECT count(DISTINCT flight_id) FROM trajectory_modes WHERE phase = 'all'").fetchall()[0][0] == n_flights
        assert con.sql("SELECT count(*) FROM flight_splits WHERE split = 'test'").fetchall()[0][0] >= 1
        wx = con.sql("SELECT min(temperature_k), max(temperature_k), max(abs(wind_u_mps)) FROM tracks_20s").fetchall()[0]
        assert 190 < wx[0] < wx[1] < 300 and wx[2] < 150


def test_metadata_has_plots_recording_and_alignment(run):
    result, home = run
    meta = {e.asset_key.to_user_string(): e.materialization.metadata for e in result.get_asset_materialization_events()}
    assert meta["tracks_20s"]["weather_alignment"].value == "time_of_day"
    assert "data:image/png;base64," in meta["tracks_20s"]["altitude_profiles"].value
    assert "data:image/png;base64," in meta["trajectory_modes"]["modes_map"].value
    assert meta["flight_tracks"]["rows"].value > 0 and "path" in meta["flight_tracks"]
    assert (home / "recordings" / "trajectory_modes.rrd").stat().st_size > 1000
    assert (home / "plots" / "altitude_profiles_by_phase.png").read_bytes()[:4] == b"\x89PNG"


def test_stored_split_is_reproducible(in_home):
    from models.aviation.split import split_flights
    from warehouse.storage import read_table

    again = split_flights(read_table("flights"), read_table("trajectory_modes"), test_fraction=0.2, seed=0)
    assert again.equals(read_table("flight_splits"))
