"""The ingest's fast paths give exactly what the plain computation gives: the spike kernel's cheap bound,
the one-key (aircraft, ts) sort and its fallback, name codes from runs, the flights table's end points, the Parquet
file read in two halves at once, and the compiled interpolation of the 20 s grid."""

import time

import numba
import pytest
import numpy as np
import polars as pl

from models.aviation.airports import flights_table
from models.aviation.order import SAMPLE_EVERY, in_flight_order, run_starts, runs
from models.aviation import kernels
from models.aviation.ingest import TS_RANGE_US, _tidy_names, _timestamps, _used_columns, clean, ingest, normalise, read_source
from models.aviation.resample import resample
from models.parallel import together
from models.aviation.resample import EARTH_RADIUS_M


def _spikes(rows: pl.DataFrame, max_speed: float, max_climb: float) -> np.ndarray:
    """Per row of `rows` (in aircraft, ts order): the spike kernel rejected it (and only it: the rows it keeps are the
    others)."""
    ac, ts = rows["_ac"].to_numpy(), rows["ts"].dt.epoch("us").to_numpy()
    lat, lon, alt = (rows[c].to_numpy() for c in ("lat", "lon", "alt_m"))
    reason = np.zeros(rows.height, dtype=np.uint8)
    kept = kernels.speed_spikes(np.arange(rows.height), ac, ts, lat, lon, alt, max_speed, max_climb, EARTH_RADIUS_M, reason).copy()
    spike = reason == kernels.SPEED_SPIKE
    np.testing.assert_array_equal(kept, np.flatnonzero(~spike))
    return spike


def _spike_oracle(rows: pl.DataFrame, max_speed: float, max_climb: float) -> np.ndarray:
    """The rule written out plainly: the exact equirectangular leg on every row, as a polars expression."""
    same = (pl.col("_ac") == pl.col("_ac").shift(1)).fill_null(False)
    dt = ((pl.col("ts") - pl.col("ts").shift(1)).dt.total_microseconds() / 1e6).clip(lower_bound=1.0)
    lat1, lon1, lat2, lon2 = pl.col("lat").shift(1), pl.col("lon").shift(1), pl.col("lat"), pl.col("lon")
    dlon = ((lon2 - lon1 + 180.0) % 360.0 - 180.0).radians() * ((lat1 + lat2) / 2).radians().cos()
    leg = EARTH_RADIUS_M * ((lat2 - lat1).radians() ** 2 + dlon**2).sqrt()
    fast = same & (leg / dt > max_speed)
    steep = same & ((pl.col("alt_m") - pl.col("alt_m").shift(1)).abs() / dt > max_climb)
    both = lambda x: (x & x.shift(-1)).fill_null(False)  # noqa: E731
    return rows.select(both(fast) | both(steep)).to_series().to_numpy()


def test_speed_spike_bound_matches_the_exact_rule():
    """Legs near the speed limit, at every latitude, across the antimeridian and with 0 s steps."""
    rng = np.random.default_rng(3)
    n = 60_000
    ac = np.sort(rng.integers(0, 40, n)).astype(np.uint32)
    ts = np.cumsum(rng.choice([0, 1, 1, 5, 20], n)) * 1_000_000
    first = np.r_[True, ac[1:] != ac[:-1]]

    def walk(start: np.ndarray, steps: np.ndarray) -> np.ndarray:
        """Each aircraft's track: its start value plus the cumulated steps of its earlier legs."""
        c = np.cumsum(np.r_[0.0, steps[:-1]])
        return start[ac] + c - c[np.flatnonzero(first)][ac]

    # every leg flown at a speed around the limit (m/s), in any direction, from each aircraft's own start
    speed = rng.choice([300.0, 349.9, 350.0, 350.1, 400.0, 2_000.0], n)
    bearing = rng.uniform(0, 2 * np.pi, n)
    step = np.r_[np.diff(ts) / 1e6, 1.0].clip(min=1.0) * speed / 6_371_000.0
    lat = np.clip(walk(rng.uniform(-85.0, 85.0, 40), np.degrees(step * np.cos(bearing))), -89.9, 89.9)
    lon = walk(rng.choice([-179.99, 0.0, 120.0, 179.99], 40), np.degrees(step * np.sin(bearing) / np.cos(np.radians(lat))))
    lon = (lon + 180.0) % 360.0 - 180.0
    lon[::997] = 179.999  # antimeridian neighbours
    lon[1::997] = -179.999
    # altitude steps around the climb limit (m/s, times the leg's seconds)
    alt = walk(np.full(40, 8_000.0), rng.choice([-150.0, -99.9, 0.0, 99.9, 100.1], n) * np.r_[np.diff(ts) / 1e6, 1.0].clip(min=1.0))
    rows = pl.DataFrame({"_ac": ac, "ts": pl.Series(ts).cast(pl.Datetime("us", "UTC")), "lat": lat, "lon": lon, "alt_m": alt})
    got = _spikes(rows, 350.0, 100.0)
    want = _spike_oracle(rows, 350.0, 100.0)
    assert want.sum() > 100, "the case must contain spikes"
    np.testing.assert_array_equal(got, want)


def test_climb_limit_is_a_rate_as_in_the_plain_rule():
    """Fractional-second steps whose climb rate is exactly at the limit: `a / dt > c` and `a > c * dt` round
    differently (found in review: 51.186829 s steps of 5118.6829 m), so the rule must compare rates."""
    n, dt_us, climb = 80, 51_186_829, 5118.682900000001
    rows = pl.DataFrame({
        "_ac": np.zeros(n, np.uint32), "ts": pl.Series(np.arange(n) * dt_us).cast(pl.Datetime("us", "UTC")),
        "lat": np.full(n, 54.0), "lon": np.full(n, 20.0), "alt_m": np.tile([0.0, climb], n // 2),
    })
    np.testing.assert_array_equal(_spikes(rows, 350.0, 100.0), _spike_oracle(rows, 350.0, 100.0))


def test_speed_spike_bound_keeps_its_slack_for_the_exact_rule_rounding():
    """Legs due east along the equator (Amazon, Congo, Borneo) at the speed limit to within 2e-11 of it: the cheap bound
    takes |Δlon| as it is, the exact rule wraps Δlon through ±180° (rounding to 180's ulp, ~1e-11 of a 1 s leg), so
    without the bound's (1 - 1e-9) slack legs the exact rule calls too fast would be cleared (found by a search in
    review). Each aircraft: the leg under test, then 5° north in a second (far too fast): its middle row is a spike
    exactly when the leg under test is too fast."""
    reach = np.degrees(350.0 / EARTH_RADIUS_M)  # degrees of longitude in 1 s at the limit, on the equator
    lon1 = np.repeat([-60.0, 20.0, 113.0], 41)
    lon2 = lon1 + reach * (1 + np.tile(np.linspace(-2e-11, 2e-11, 41), 3))
    n = lon1.size
    rows = pl.DataFrame({
        "_ac": np.repeat(np.arange(n, dtype=np.uint32), 3), "ts": pl.Series(np.tile([0, 1, 2], n) * 1_000_000).cast(pl.Datetime("us", "UTC")),
        "lat": np.tile([0.0, 0.0, 5.0], n), "lon": np.stack([lon1, lon2, lon2], 1).ravel(), "alt_m": np.full(3 * n, 10_000.0),
    })
    want = _spike_oracle(rows, 350.0, 100.0)
    assert (want[1::3] & (lon2 - lon1 <= reach)).any(), "the case must hold legs too fast for the exact rule within |Δlon| of the reach"
    np.testing.assert_array_equal(_spikes(rows, 350.0, 100.0), want)


def test_flights_table_when_the_first_flight_has_no_airport(opensky_small):
    """No airport near the first flight's ends (Southern Ocean, cruise altitude) and airports for the others: one row
    per flight, the first one's origin and destination UNKNOWN (polars cannot cast such an object array to String)."""
    tracks = ingest(opensky_small)[0]
    first = tracks.filter(pl.col("flight_id") == tracks["flight_id"].min())
    lost = first.with_columns(flight_id=pl.lit("AAA_lost"), callsign=pl.lit("AAALOST"), lat=pl.col("lat") - 54.0 - 60.0,
                              lon=pl.col("lon") - 20.0 - 120.0, alt_m=pl.lit(11_000.0))
    flights = flights_table(pl.concat([lost, tracks]))
    assert flights.height == tracks["flight_id"].n_unique() + 1
    row = flights.filter(pl.col("flight_id") == "AAA_lost")
    assert row["origin"].to_list() == ["UNKNOWN"] and row["destination"].to_list() == ["UNKNOWN"]
    assert (flights.filter(pl.col("flight_id") != "AAA_lost")["origin"] != "UNKNOWN").any()


def _order(ac, ts, missing):
    """The kernel's order of the rows not missing (every time in range: the range is the widest int64 one)."""
    reason = np.zeros(len(ac), dtype=np.uint8)
    order = kernels.aircraft_time_order(ac, ts, missing, np.iinfo(np.int64).min, np.iinfo(np.int64).max, reason)
    np.testing.assert_array_equal(reason, np.where(missing, kernels.MISSING_VALUE, 0))
    return order


def test_aircraft_time_order_equals_a_full_sort():
    """Random rows (every aircraft's times in many runs, equal times), and rows in runs of one aircraft in time order as
    state vectors come, some runs of an aircraft overlapping in time."""
    rng = np.random.default_rng(5)
    n = 20_000
    for span_us in (10**12, 2**60):  # 12 days; ~36,000 years
        rows = pl.DataFrame(
            {
                "_ac": rng.integers(0, 3_000, n).astype(np.uint32),
                "ts": rng.integers(-span_us // 2, span_us // 2, n) // 7 * 7,
            }
        ).with_row_index("row_index")
        missing = rng.random(n) < 0.1
        # a missing row's time may be anything
        ts = np.where(missing, np.iinfo(np.int64).min, rows["ts"].to_numpy())
        want = rows.filter(~missing).sort("_ac", "ts", "row_index")["row_index"].to_numpy()
        np.testing.assert_array_equal(_order(rows["_ac"].to_numpy(), ts, missing), want)
    lengths = rng.integers(1, 200, 300)  # 300 runs of one aircraft (of 40), each in time order, overlapping in time
    for span_us in (10**6, 50):  # with few equal times; with many, across runs (the first of them in row order first)
        ac = np.repeat(rng.integers(0, 40, 300), lengths).astype(np.uint32)
        ts = np.concatenate([np.sort(rng.integers(0, span_us, k)) for k in lengths])
        want = pl.DataFrame({"ac": ac, "ts": ts}).with_row_index().sort("ac", "ts", "index")["index"].to_numpy()
        np.testing.assert_array_equal(_order(ac, ts, np.zeros(len(ac), dtype=bool)), want)
    # hours of one aircraft stored out of order (as in the bundled file), each ending at the next one's first time
    hours = rng.permutation(12)
    ts = np.concatenate([np.arange(h * 3600, (h + 1) * 3600 + 1, 8) for h in hours])
    assert len(np.unique(ts)) < len(ts)
    np.testing.assert_array_equal(_order(np.zeros(len(ts), dtype=np.uint32), ts, np.zeros(len(ts), dtype=bool)), np.argsort(ts, kind="stable"))


@pytest.mark.parametrize("layout", ["newest_first", "shuffled", "two_feeds"])
def test_aircraft_time_order_of_rows_in_no_time_order(layout):
    """One aircraft's 200,000 rows in runs of one or two rows (a file stored newest first, shuffled, or two feeds
    interleaved): a stable sort, in well under a second (merging run by run looked at every run for each stretch:
    ~15 s for 80,000 rows newest first)."""
    rng = np.random.default_rng(11)
    n = 200_000
    ts = {
        "newest_first": np.arange(n)[::-1] // 3,  # equal times in threes
        "shuffled": rng.integers(0, n // 4, n),
        "two_feeds": np.ravel(np.c_[np.arange(n // 2), np.arange(n // 2) + 5]),
    }[layout].astype(np.int64)
    _order(np.zeros(3, dtype=np.uint32), np.array([2, 1, 0]), np.zeros(3, dtype=bool))  # compiled (or loaded) first
    start = time.perf_counter()
    order = _order(np.zeros(n, dtype=np.uint32), ts, np.zeros(n, dtype=bool))
    assert time.perf_counter() - start < 2.0
    np.testing.assert_array_equal(order, np.argsort(ts, kind="stable"))


def test_timestamps_in_ms_beyond_range_stay_out_of_range():
    """Milliseconds whose µs do not fit an int64 (a decoding error) are clipped, not wrapped into the years of real
    data: the row rules then reject them as out of range."""
    ms = pl.Series([2**62, 18_448_389_573_709_551, -(2**62), 1_645_499_999_999, None], dtype=pl.Int64).cast(pl.Datetime("ms"))
    us = _timestamps(ms, "x").to_physical().to_list()
    assert us[4] is None and us[3] == 1_645_499_999_999_000
    assert all(not TS_RANGE_US[0] <= v < TS_RANGE_US[1] for v in us[:3])


def test_aircraft_time_order_with_extreme_codes_and_times():
    """Aircraft codes of 11 to 14 bits beside a 51-bit time span (a day of worldwide data has ~8,000 aircraft, 13 bits;
    one time at 1970-01-01 among 2022's gives 51 bits: what overflowed the one int64 key of an earlier sort). Row 0 is
    missing; rows 1 and 3 are the highest aircraft code, row 1 at the end of the span."""
    span = 2**51 - 1  # µs: 1970-01-01 to 2041-05-06
    for ac_bits in (11, 12, 13, 14):
        top = 2**ac_bits - 1
        ac = np.array([0, top, 0, top, 1], dtype=np.uint32)
        ts = np.array([0, span, 0, 1, 5], dtype=np.int64)
        missing = np.array([True, False, False, False, False])
        np.testing.assert_array_equal(_order(ac, ts, missing), [2, 4, 3, 1], err_msg=f"{ac_bits} bits")


def test_kernels_get_the_same_types_from_one_chunk_or_several(monkeypatch, opensky_small):
    """A file read in several chunks (many Parquet row groups, a CSV read in parallel) hands numpy copies, one in one
    chunk polars' read-only memory: the kernels must see the same types, or numba compiles them again (~4 s)."""
    seen = []
    for name in ("point_rules", "speed_spikes", "flight_starts"):
        kernel = getattr(kernels, name)
        monkeypatch.setattr(kernels, name, lambda *a, _k=kernel: seen.append(tuple(map(numba.typeof, a))) or _k(*a))
    df = pl.read_parquet(opensky_small)
    for frame in (df, pl.concat([df[:1000], df[1000:]], rechunk=False)):
        clean(normalise(frame, "x"), "x")
    # as sets: the two halves of the rows call the kernels from two threads, in either order
    assert seen and set(seen[: len(seen) // 2]) == set(seen[len(seen) // 2 :])


def test_name_codes_sort_like_the_tidy_names_in_runs_or_not():
    raw = pl.Series(["AFL1 ", "AFL1", "", None, "sdm2", "  SDM2", "AFL1", "abc", "abc", "abc"], dtype=pl.String)
    for names in (raw, raw.gather(np.random.default_rng(0).permutation(raw.len()))):  # runs, and shuffled
        for lower in (False, True):
            tidy, code = _tidy_names(names, lower)
            want = names.str.strip_chars()
            want = (want.str.to_lowercase() if lower else want).replace("", None)
            assert tidy.to_list() == want.to_list()
            assert code.is_null().to_list() == want.is_null().to_list()
            assert code.to_list() == (want.rank("dense").cast(pl.UInt32) - 1).to_list()


def test_shuffled_file_gives_the_same_tracks(tmp_path, opensky_small):
    """Unsorted input takes the general sort; tracks and reasons must not depend on the row order."""
    df = pl.read_parquet(opensky_small)
    perm = np.random.default_rng(2).permutation(df.height)
    df.write_parquet(tmp_path / "a.parquet")
    df[perm].write_parquet(tmp_path / "b.parquet")
    ta, ra, _ = ingest(tmp_path / "a.parquet")
    tb, rb, _ = ingest(tmp_path / "b.parquet")
    assert ta.equals(tb)
    # the same rows rejected for the same reasons (a duplicate keeps its first copy, so compare the counts)
    assert dict(ra["reason"].value_counts().rows()) == dict(rb["reason"].value_counts().rows())


def test_flights_table_end_points_equal_a_group_by(opensky_small):
    tracks = ingest(opensky_small)[0]
    short = pl.concat([tracks, tracks.group_by("flight_id", maintain_order=True).head(5).with_columns(pl.col("flight_id") + "_x")])
    got = flights_table(short)
    want = short.group_by("flight_id").agg(
        pl.col("callsign", "icao24").first(), first_ts=pl.col("ts").min(), last_ts=pl.col("ts").max(), n_points=pl.len().cast(pl.Int64)
    )
    assert got.select(want.columns).equals(want.sort("flight_id"))
    assert set(got.filter(pl.col("flight_id").str.ends_with("_x"))["n_points"]) == {5}


def test_in_flight_order_sorts_exactly_when_needed():
    ts = pl.Series([0, 5, 9, 1, 2, 3], dtype=pl.Int64).cast(pl.Datetime("us", "UTC"))
    ordered = pl.DataFrame({"flight_id": ["a", "a", "a", "b", "b", "b"], "ts": ts, "x": range(6)})
    flagged = in_flight_order(ordered)  # a later flight may start earlier in time: no sort, flight_id flagged sorted
    assert flagged.equals(ordered) and flagged["flight_id"].flags["SORTED_ASC"]
    assert in_flight_order(flagged) is flagged
    for broken in (
        ordered.with_columns(ts=ts.gather([1, 0, 2, 3, 4, 5])),  # time runs back within a flight
        ordered.with_columns(ts=ts.gather([0, 0, 2, 3, 4, 5])),  # a repeated time
        ordered.with_columns(flight_id=pl.Series(["b", "b", "b", "a", "a", "a"])),  # flights out of order
    ):
        assert in_flight_order(broken).equals(broken.sort("flight_id", "ts"))
        assert in_flight_order(broken) is not broken


def test_parquet_read_in_two_halves_equals_one_read(tmp_path, opensky_small):
    """The used columns, in file order, whatever the row groups, with columns ingest does not use (a nested one too:
    OpenSky exports carry a list of serials) left out; a file of one used column reads too."""
    df = pl.read_parquet(opensky_small).with_columns(serials=pl.concat_list(pl.lit(1), pl.lit(2)), squawk=pl.lit("7000"))
    path = tmp_path / "many_groups.parquet"
    df.write_parquet(path, row_group_size=5_000)
    want = pl.read_parquet(path, columns=_used_columns(df.columns))
    assert read_source(path).equals(want)
    only = tmp_path / "one.parquet"
    df.select("lat").write_parquet(only)
    assert read_source(only).equals(df.select("lat"))


def test_together_returns_results_in_order_and_raises_a_callee_error():
    assert together(lambda: 1, lambda: 2, lambda: 3) == [1, 2, 3]

    def fails():
        raise ValueError("from a thread")

    with pytest.raises(ValueError, match="from a thread"):
        together(fails, lambda: 2)


@pytest.mark.timeout(60)
def test_together_nested_deeper_than_the_pool_has_threads_does_not_wait_forever():
    """Inner calls from the pool's threads run in the calling thread instead of waiting on the busy pool."""
    nested = lambda depth: 1 if depth == 0 else sum(together(*(lambda: nested(depth - 1) for _ in range(3))))  # noqa: E731
    assert nested(4) == 3**4


def test_interpolation_kernel_gets_the_same_types_from_one_chunk_or_several(monkeypatch, opensky_small):
    """As for the ingest kernels: tracks in one chunk or several must not compile the kernels a second time."""
    seen = []
    for name in ("grid_rows", "interpolate"):
        kernel = getattr(kernels, name)
        monkeypatch.setattr(kernels, name, lambda *a, _k=kernel: seen.append(tuple(map(numba.typeof, a))) or _k(*a))
    tracks, _, _ = ingest(opensky_small)
    half = tracks.height // 2
    for frame in (tracks, pl.concat([tracks[:half], tracks[half:]], rechunk=False)):
        resample(frame)
    assert seen and set(seen[: len(seen) // 2]) == set(seen[len(seen) // 2 :])  # the columns run in threads, in any order


def test_run_starts_of_a_sorted_column_equal_a_run_length_pass():
    """Runs longer than the sampling step, runs shorter than it that no sample sees (the check must send them to the
    run-length pass), a run starting on a sample, one value, nulls, and a column not flagged sorted."""
    rng = np.random.default_rng(8)
    cases = [
        np.repeat(np.arange(50), rng.integers(SAMPLE_EVERY, 5 * SAMPLE_EVERY, 50)),
        np.repeat(np.arange(50), rng.integers(1, 3 * SAMPLE_EVERY, 50)),
        np.repeat(np.arange(3), [SAMPLE_EVERY, SAMPLE_EVERY, 1]),
        np.repeat(np.arange(3), [SAMPLE_EVERY - 1, 2, SAMPLE_EVERY]),  # the middle run falls between two samples
        np.zeros(10, dtype=int),
    ]
    for ids in cases:
        names = pl.Series([f"f{i:03d}" for i in ids])
        want = runs(names)[1]
        np.testing.assert_array_equal(run_starts(names.set_sorted()), want)
        np.testing.assert_array_equal(run_starts(names), want)
    with_null = pl.Series([None, "a", "a", "b"]).set_sorted()
    np.testing.assert_array_equal(run_starts(with_null), [0, 1, 3])
