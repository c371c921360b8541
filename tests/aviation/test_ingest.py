"""Ingest on real OpenSky data, and every kind of bad input giving one clear line or a quarantine entry."""

import gzip

import numpy as np
import polars as pl
import pytest

from models.aviation.ingest import IngestConfig, IngestError, ingest
from models.units import M_PER_FT, MPS_PER_KT
from tests.conftest import OPENSKY


def test_real_data_every_row_accounted():
    tracks, rejects, summary = ingest(OPENSKY)
    read = summary.filter(pl.col("outcome") == "read")["rows"][0]
    assert read == 528_432
    assert tracks.height + rejects.height == read
    assert summary.filter(pl.col("outcome") != "read")["rows"].sum() == read
    assert tracks["flight_id"].n_unique() == 93
    # OpenSky repeats stale positions; they must be quarantined, not kept
    assert rejects.filter(pl.col("reason") == "repeated_position").height > 100_000
    assert tracks.group_by("flight_id").agg(ok=(pl.col("ts").diff().dt.total_seconds() > 0).all())["ok"].all()
    assert tracks.equals(tracks.sort("flight_id", "ts")), "tracks come out in (flight_id, ts) order"


def test_real_data_airports():
    from models.aviation.airports import flights_table

    flights = flights_table(ingest(OPENSKY)[0])
    assert dict(flights["route"].value_counts().rows()) == {"UUEE-UMKK": 57, "ULLI-UMKK": 36}
    assert flights["origin_distance_nm"].max() < 10
    # coverage ends before landing (12-161 NM short of UMKK): the distance is recorded, not hidden
    assert 5 < flights["destination_distance_nm"].min() < 20 < 150 < flights["destination_distance_nm"].max() < 170


def _write(df: pl.DataFrame, path):
    df.write_parquet(path) if path.suffix == ".parquet" else df.write_csv(path)
    return path


@pytest.fixture
def small_raw(opensky_small) -> pl.DataFrame:
    return pl.read_parquet(opensky_small)


def test_nan_unsorted_duplicated_rows_are_quarantined(small_raw, tmp_path):
    df = small_raw.with_row_index("i")
    complete = pl.all_horizontal(pl.col("lat", "lon", "baroaltitude").is_not_null()) & (pl.col("i") % 101 != 0)
    dup = df.filter((pl.col("i") % 97 == 0) & complete)
    nan = df.filter(pl.col("i") % 101 == 0).with_columns(lat=pl.lit(float("nan")))
    bad = pl.concat([df.filter(pl.col("i") % 101 != 0), nan, dup]).sample(fraction=1.0, shuffle=True, seed=1).drop("i")
    tracks, rejects, summary = ingest(_write(bad, tmp_path / "messy.parquet"))
    assert tracks.height + rejects.height == bad.height
    reasons = dict(rejects["reason"].value_counts().rows())
    assert reasons["duplicate_row"] == dup.height
    assert reasons["missing_value"] >= nan.height
    clean_tracks, _, _ = ingest(_write(small_raw, tmp_path / "clean.parquet"))
    assert tracks["flight_id"].n_unique() == clean_tracks["flight_id"].n_unique()


def test_traffic_style_csv_units(small_raw, tmp_path):
    traffic = small_raw.select(
        timestamp=pl.col("time"),
        icao24="icao24",
        callsign="callsign",
        latitude="lat",
        longitude="lon",
        altitude=pl.col("baroaltitude") / M_PER_FT,
        groundspeed=pl.col("velocity") / MPS_PER_KT,
        track="heading",
        vertical_rate=pl.col("vertrate") / M_PER_FT * 60,
    )
    t_csv, _, _ = ingest(_write(traffic, tmp_path / "traffic.csv"))
    t_pq, _, _ = ingest(_write(small_raw, tmp_path / "opensky.parquet"))
    assert t_csv["alt_m"].max() == pytest.approx(t_pq["alt_m"].max(), rel=1e-6)
    assert t_csv["groundspeed_mps"].median() == pytest.approx(small_raw["velocity"].median(), rel=0.05)


def test_json_gz_epoch_ms(tmp_path, small_raw):
    recs = small_raw.head(5000).select(
        timestamp=pl.col("time").dt.epoch("ms"), icao24="icao24", callsign="callsign", latitude="lat",
        longitude="lon", altitude=pl.col("baroaltitude") / M_PER_FT,
    )
    path = tmp_path / "sample.json.gz"
    with gzip.open(path, "wt") as f:
        f.write(recs.write_json())
    tracks, rejects, _ = ingest(path, IngestConfig(min_points=5))
    assert tracks.height + rejects.height == 5000
    assert tracks["ts"].dt.year().unique().to_list() == [2022]


def test_a_csv_column_empty_in_its_first_rows_is_read_as_numbers(small_raw, tmp_path):
    # polars reads such a column as text (it infers types from the first 10,000 rows): an export without vertical
    # rates, or one whose altitudes start late, was refused as "is String, expected numbers"; late position times as
    # "not timestamps", a late on-ground flag was a polars traceback (text cast to booleans)
    starts_late = pl.when(pl.col("i") >= 10_000).then
    late = small_raw.with_row_index("i").with_columns(
        baroaltitude=starts_late(pl.col("baroaltitude")), lastposupdate=starts_late(pl.col("lastposupdate")),
        onground=starts_late(pl.col("onground")), vertrate=pl.lit(None, pl.Float64)).drop("i")
    tracks, rejects, _ = ingest(_write(late, tmp_path / "late.csv"))
    typed, typed_rejects, _ = ingest(_write(late, tmp_path / "late.parquet"))  # the same values, typed
    assert tracks.height > 0 and tracks.equals(typed) and rejects.drop("source").equals(typed_rejects.drop("source"))
    assert dict(rejects.group_by("reason").len().iter_rows())["missing_value"] >= 10_000
    with pytest.raises(IngestError, match="column 'baroaltitude' is String, expected numbers"):  # text that is not numbers
        ingest(_write(small_raw.with_columns(pl.col("baroaltitude").cast(pl.String) + " m"), tmp_path / "units.csv"))
    with pytest.raises(IngestError, match="column 'onground' is text, expected true/false"):
        ingest(_write(small_raw.with_columns(onground=pl.lit("yes")), tmp_path / "flag.csv"))


@pytest.mark.parametrize(
    "make, message",
    [
        (lambda p, raw: p / "nope.parquet", "no such file"),
        (lambda p, raw: (p / "empty.csv").write_text("time,icao24,lat,lon,baroaltitude\n") and p / "empty.csv", "no rows"),
        (lambda p, raw: (p / "x.parquet").write_bytes(b"this is not parquet") and p / "x.parquet", "not a readable parquet"),
        (lambda p, raw: _write(pl.DataFrame(), p / "no_columns.parquet"), "no rows"),
        (lambda p, raw: (p / "notes.txt").write_text("hello") and p / "notes.txt", "unsupported file type '.txt', expected .parquet, .csv, .tsv, .json, .jsonl or .ndjson (the text ones may be gzipped: .csv.gz)"),
        (lambda p, raw: _write(raw.drop("lat"), p / "nolat.parquet"), "missing columns ['lat']"),
        (lambda p, raw: _write(raw.with_columns(pl.col("baroaltitude") / M_PER_FT), p / "feet.parquet"), "looks like feet"),
        (lambda p, raw: _write(raw.with_columns(pl.col("velocity") * 3.6 * 10), p / "speed.parquet"), "wrong unit"),
        (lambda p, raw: _write(raw.with_columns(time=pl.lit("yesterday")), p / "badtime.csv"), "not timestamps"),
        (lambda p, raw: p, "is a folder"),
    ],
)
def test_bad_input_gives_one_line_error(tmp_path, small_raw, make, message):
    path = make(tmp_path, small_raw)
    with pytest.raises(IngestError) as err:
        ingest(path)
    text = str(err.value)
    assert message in text
    assert "\n" not in text


@pytest.mark.parametrize("to_unit", [1.0, 3.0], ids=["metres", "thirds"])
def test_traffic_altitude_in_metres_is_refused(tmp_path, small_raw, to_unit):
    traffic = small_raw.select(
        timestamp="time", icao24="icao24", latitude="lat", longitude="lon", altitude=pl.col("baroaltitude") / to_unit,
        groundspeed=pl.col("velocity") / MPS_PER_KT,
    )
    with pytest.raises(IngestError, match="looks like metres or flight levels"):
        ingest(_write(traffic, tmp_path / "m.csv"))


def test_traffic_feet_cut_to_low_levels_is_kept(tmp_path, small_raw):
    """Feet data of a low sector (FL100-FL150) flown at airliner speed is not mistaken for metres."""
    traffic = small_raw.select(
        timestamp="time", icao24="icao24", latitude="lat", longitude="lon", groundspeed=pl.col("velocity") / MPS_PER_KT,
        altitude=(pl.col("baroaltitude") / M_PER_FT).clip(10_000, 15_000),
    )
    tracks, _, _ = ingest(_write(traffic, tmp_path / "low.csv"))
    assert tracks.height > 0 and tracks["alt_m"].max() == pytest.approx(15_000 * M_PER_FT)


def test_times_outside_1970_2100_are_quarantined(small_raw, tmp_path):
    """A decoded time in the year 292,277 or before 1970 is out of range: quarantined, not sorted into a flight (before,
    a flight name's date made polars panic, and differences of such times overflowed)."""
    us = small_raw["time"].dt.epoch("us")
    far = pl.Series([2**63 - 10, -(2**62), -1, 4_102_444_800_000_000])  # year 292,277; 146,000 BC; 1969; 2100-01-01
    bad = small_raw.with_columns(
        time=pl.concat([far, us.slice(len(far))]).cast(pl.Datetime("us", "UTC"))
    )
    tracks, rejects, summary = ingest(_write(bad, tmp_path / "far.parquet"))
    assert tracks.height + rejects.height == bad.height
    assert set(rejects.filter(pl.col("row_index") < len(far))["reason"]) == {"out_of_range"}
    assert tracks["ts"].dt.year().is_between(1970, 2099).all()
    assert tracks["flight_id"].n_unique() == ingest(_write(small_raw, tmp_path / "clean.parquet"))[0]["flight_id"].n_unique()


def test_spikes_and_ground_points_rejected(tmp_path, small_raw):
    df = small_raw.with_row_index("i")
    spike_rows = df.filter(pl.col("lastposupdate").is_not_null()).gather_every(5003)["i"]
    bad = df.with_columns(
        lat=pl.when(pl.col("i").is_in(spike_rows.implode())).then(pl.col("lat") + 3.0).otherwise("lat"),
        lastposupdate=pl.when(pl.col("i").is_in(spike_rows.implode())).then(pl.col("lastposupdate") + 0.5).otherwise("lastposupdate"),
    ).drop("i")
    tracks, rejects, _ = ingest(_write(bad, tmp_path / "spikes.parquet"))
    spiked = rejects.filter(pl.col("reason") == "speed_spike")["row_index"].to_numpy()
    assert np.isin(spike_rows.to_numpy(), spiked).mean() > 0.8
    assert tracks["lat"].max() < small_raw["lat"].max() + 0.01


def test_callsigns_fill_split_and_fallback(tmp_path, small_raw):
    """A callsign missing mid-flight is carried forward (no new flight), a callsign change starts a flight,
    an aircraft that never sends one keeps its icao24 as callsign; ids that are not ICAO hex work too."""
    first = small_raw.filter(pl.col("callsign").is_not_null())["icao24"][0]
    one = small_raw.filter(pl.col("icao24") == first).sort("time")
    clean_tracks = ingest(_write(one, tmp_path / "one.parquet"))[0]
    clean_ids = clean_tracks["flight_id"].unique()
    n = one.height
    gappy = one.with_columns(callsign=pl.when(pl.int_range(n) % 7 == 3).then(None).otherwise("callsign"))
    gappy_tracks = ingest(_write(gappy, tmp_path / "gappy.parquet"))[0]
    assert gappy_tracks["flight_id"].unique().equals(clean_ids)
    assert set(gappy_tracks["callsign"]) == set(one["callsign"].drop_nulls().str.strip_chars())
    # the aircraft's longest flight relabelled half-way: one flight more, the second half with the new callsign
    longest = clean_tracks.group_by("flight_id").len().sort("len")["flight_id"][-1]
    tracks = clean_tracks.filter(pl.col("flight_id") == longest)
    cut = tracks["ts"][tracks.height // 2]
    renamed = one.with_columns(callsign=pl.when(pl.col("time") >= cut).then(pl.lit("NEW123")).otherwise("callsign"))
    split = ingest(_write(renamed, tmp_path / "renamed.parquet"))[0]
    assert split["flight_id"].n_unique() == clean_ids.len() + 1
    assert split.filter(pl.col("ts") >= cut)["callsign"].unique().to_list() == ["NEW123"]
    # no callsign at all and a non-hex transponder id
    anon = one.with_columns(callsign=pl.lit(None, pl.String), icao24=pl.lit("Test-7"))
    anon_tracks, anon_rejects, _ = ingest(_write(anon, tmp_path / "anon.parquet"))
    assert anon_tracks.height + anon_rejects.height == n
    assert anon_tracks["callsign"].unique().to_list() == ["test-7"]
    assert anon_tracks["flight_id"].n_unique() == clean_ids.len()


def _state_vectors(icao24: list, callsign: list, lastposupdate: list) -> pl.DataFrame:
    """OpenSky rows a second apart, each 0.001° further north (a plausible track: no rule but the one under test hits)."""
    n = len(icao24)
    return pl.DataFrame({
        "time": pl.Series(1_650_000_000 + np.arange(n), dtype=pl.Int64), "icao24": icao24, "callsign": pl.Series(callsign, dtype=pl.String),
        "lat": 54.0 + 0.001 * np.arange(n), "lon": np.full(n, 20.0), "baroaltitude": np.full(n, 10_000.0),
        "lastposupdate": pl.Series(lastposupdate, dtype=pl.Float64),
    })


def test_an_aircraft_without_a_callsign_is_named_by_its_own_icao24(tmp_path):
    """The file's first row has a callsign (AFL1) and another aircraft never sends one: that one's flight is named and
    labelled by its icao24, not by another row's callsign."""
    rows = _state_vectors(["aaa111"] * 3 + ["bbb222"] * 3, ["AFL1"] * 3 + [None] * 3, [None] * 6)
    tracks = ingest(_write(rows, tmp_path / "two.parquet"), IngestConfig(min_points=1))[0]
    anon = tracks.filter(pl.col("icao24") == "bbb222")
    assert anon["callsign"].to_list() == ["bbb222"] * 3
    assert anon["flight_id"].str.starts_with("bbb222_bbb222_").all()


def test_a_position_time_of_zero_after_none_is_a_new_position(tmp_path):
    """A row with no position time, then one whose lastposupdate is 0 (1970-01-01: a field never set) at a new place:
    the second is kept. The kernel reads a missing position time as 0.0 beside a has-position flag, so a repeat must
    need a position time on both rows."""
    rows = _state_vectors(["aaa111"] * 2, ["AFL1"] * 2, [None, 0.0])
    tracks, rejects, _ = ingest(_write(rows, tmp_path / "zero.parquet"), IngestConfig(min_points=1))
    assert tracks.height == 2 and rejects.height == 0


def test_aircraft_ids_that_parse_alike_stay_apart(tmp_path, small_raw):
    """'+abcde' and '0abcde' are the same hex number but two aircraft (here flying the same track at the same
    time: merged, one would be all duplicates); a blank icao24 is a missing one."""
    one = small_raw.filter(pl.col("icao24") == small_raw["icao24"][0])
    reference = ingest(_write(one, tmp_path / "ref.parquet"))[0]
    pair = pl.concat([one.with_columns(icao24=pl.lit(name)) for name in ("+abcde", "0abcde")])
    tracks, rejects, _ = ingest(_write(pair, tmp_path / "pair.parquet"))
    assert tracks.height == 2 * reference.height and "duplicate_row" not in set(rejects["reason"])
    assert set(tracks["icao24"]) == {"+abcde", "0abcde"}
    blank = pair.with_columns(icao24=pl.when(pl.col("icao24") == "+abcde").then(pl.lit("  ")).otherwise("icao24"))
    tracks, rejects, _ = ingest(_write(blank, tmp_path / "blank.parquet"))
    blanked = rejects.filter(pl.col("row_index") < one.height)  # the first copy's rows
    assert blanked.height == one.height and set(blanked["reason"]) == {"missing_value"}
    assert set(tracks["icao24"]) == {"0abcde"}


def test_flights_shorter_than_the_heading_window(tmp_path, small_raw):
    """Flights of fewer than 11 points get a flights-table row (no heading-based airport, as before), no error."""
    from models.aviation.airports import flights_table

    tracks = ingest(_write(small_raw, tmp_path / "all.parquet"))[0]
    short = tracks.group_by("flight_id", maintain_order=True).head(7)
    flights = flights_table(short)
    assert flights.height == tracks["flight_id"].n_unique()
    assert (flights["n_points"] == 7).all()


def test_every_row_rejected_gives_empty_tracks(tmp_path, small_raw):
    """A file whose rows all fail the first stage (no aircraft address) ends with no track, every row quarantined."""
    no_address = small_raw.with_columns(icao24=pl.lit(None, pl.String))
    tracks, rejects, _ = ingest(_write(no_address, tmp_path / "anonymous.parquet"))
    assert tracks.height == 0 and rejects.height == no_address.height
    assert set(rejects["reason"]) == {"missing_value"}


def test_ingest_asset_refuses_to_keep_no_flight(tmp_path, small_raw):
    """Every row rejected (here: every segment too short) must not replace the warehouse tables with empty ones."""
    import dagster as dg

    from assets.aviation.ingest import flight_ingest
    from warehouse.io_manager import ParquetIOManager

    path = _write(small_raw, tmp_path / "six.parquet")
    result = dg.materialize(
        [flight_ingest], resources={"io_manager": ParquetIOManager()}, raise_on_error=False,
        run_config={"ops": {"flight_ingest": {"config": {"source_path": str(path), "min_points": 10**9}}}},
    )
    assert not result.success
    (failure,) = [e for e in result.all_events if e.is_step_failure]
    message = failure.step_failure_data.error.cause.message
    assert "no flight kept of" in message and "short_segment=" in message


def test_the_rules_see_an_aircraft_whole_when_the_rows_are_cut_in_two(tmp_path):
    """The rules run on two halves of the rows at once, cut between aircraft: aircraft aaa111's second and third rows
    (a duplicate) sit at the middle of the five rows, where a cut inside the aircraft would keep both."""
    rows = _state_vectors(["aaa111"] * 4 + ["bbb222"], ["AFL1"] * 4 + ["SDM2"], [None] * 5)
    rows = rows.with_columns(time=pl.Series([0, 1, 1, 2, 0], dtype=pl.Int64) + 1_650_000_000)
    tracks, rejects, _ = ingest(_write(rows, tmp_path / "cut.parquet"), IngestConfig(min_points=1))
    assert rejects["reason"].to_list() == ["duplicate_row"] and rejects["row_index"].to_list() == [2]
    assert tracks.height == 4


def test_rows_before_an_aircraft_first_callsign_keep_its_icao24(tmp_path):
    """An aircraft that sends its callsign from its third row on: one flight, named by its first point (the icao24),
    whose first two rows carry the icao24 as callsign and the others the callsign; a second flight after a gap
    carries the callsign on every row."""
    rows = _state_vectors(["aaa111"] * 6, [None, None, "AFL1", "AFL1", None, "AFL1"], [None] * 6)
    rows = rows.with_columns(time=pl.Series([0, 1, 2, 3, 4000, 4001], dtype=pl.Int64) + 1_650_000_000)
    tracks = ingest(_write(rows, tmp_path / "late.parquet"), IngestConfig(min_points=1))[0].sort("ts")
    assert tracks["callsign"].to_list() == ["aaa111", "aaa111", "AFL1", "AFL1", "AFL1", "AFL1"]
    assert tracks["flight_id"].str.slice(0, 14).to_list() == ["aaa111_aaa111_"] * 4 + ["AFL1_aaa111_20"] * 2
