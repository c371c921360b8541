"""20 s resampling and phase segmentation on real flights."""

import numpy as np
import polars as pl
import pytest

from models.aviation.airports import airports_table, flights_table
from models.aviation.ingest import ingest
from models.aviation.phases import PHASES, PhaseConfig, assign_phases, phase_table
from models.aviation.resample import resample


@pytest.fixture(scope="module")
def cleaned(opensky_small):
    tracks, _, _ = ingest(opensky_small)
    return tracks, flights_table(tracks)


def test_constant_step_grid(cleaned):
    tracks, _ = cleaned
    grid = resample(tracks, 20.0)
    steps = grid.with_columns(d=pl.col("ts").diff().over("flight_id").dt.total_seconds())["d"].drop_nulls()
    assert set(steps.unique().to_list()) == {20}
    assert (grid["ts"].dt.epoch("s") % 20 == 0).all()
    assert grid.null_count().sum_horizontal()[0] == 0
    assert grid["flight_id"].n_unique() == tracks["flight_id"].n_unique()
    # every grid point lies inside its flight's span: no bleeding between flights
    span = tracks.group_by("flight_id").agg(t0=pl.col("ts").min(), t1=pl.col("ts").max())
    inside = grid.join(span, on="flight_id").select(((pl.col("ts") >= pl.col("t0")) & (pl.col("ts") <= pl.col("t1"))).all())
    assert inside.item()


def test_constant_speed_between_reports():
    """Two reports 60 s apart: the 20 s points lie evenly between them (constant speed)."""
    t = pl.DataFrame(
        {
            "flight_id": ["a", "a"],
            "ts": pl.Series(["2022-01-01T00:00:00", "2022-01-01T00:01:00"]).str.to_datetime(time_zone="UTC").cast(pl.Datetime("us", "UTC")),
            "lat": [50.0, 50.3], "lon": [179.9, -179.9], "alt_m": [1000.0, 1600.0],
            "groundspeed_mps": [200.0, 200.0], "track_deg": [350.0, 10.0], "vertical_rate_mps": [10.0, 10.0],
        }
    )
    g = resample(t, 20.0)
    assert g["lat"].to_list() == pytest.approx([50.0, 50.1, 50.2, 50.3])
    assert g["alt_m"].to_list() == pytest.approx([1000, 1200, 1400, 1600])
    # across the antimeridian and through north, not the long way round
    assert g["lon"].to_list() == pytest.approx([179.9, 179.9666667, -179.9666667, -179.9])
    assert all(d < 10.001 or d > 349.999 for d in g["track_deg"].to_list())


def test_rates_derived_when_source_has_none():
    t = pl.DataFrame(
        {
            "flight_id": ["a"] * 3,
            "ts": pl.datetime_range(pl.datetime(2022, 1, 1, time_zone="UTC"), pl.datetime(2022, 1, 1, 0, 0, 40, time_zone="UTC"), "20s", eager=True).cast(pl.Datetime("us", "UTC")),
            "lat": [50.0, 50.0, 50.0], "lon": [10.0, 10.01, 10.02], "alt_m": [1000.0, 1100.0, 1200.0],
            "groundspeed_mps": [None] * 3, "track_deg": [None] * 3, "vertical_rate_mps": [None] * 3,
        },
        schema_overrides={"groundspeed_mps": pl.Float64, "track_deg": pl.Float64, "vertical_rate_mps": pl.Float64},
    )
    g = resample(t, 20.0)
    assert g["vertical_rate_mps"].to_list() == pytest.approx([5.0, 5.0, 5.0])
    assert g["track_deg"].to_list() == pytest.approx([90.0] * 3, abs=0.1)
    assert g["groundspeed_mps"][1] == pytest.approx(715.5 / 20, rel=0.01)


@pytest.mark.parametrize("method", ["vertical", "regions"])
def test_phases_in_order_and_sensible(cleaned, method):
    tracks, flights = cleaned
    grid = assign_phases(resample(tracks), flights, PhaseConfig(method=method), airports_table())
    rank = grid.with_columns(r=pl.col("phase").replace_strict({p: i for i, p in enumerate(PHASES)}, return_dtype=pl.Int8))
    assert rank.select((pl.col("r").diff().over("flight_id").fill_null(0) >= 0).all()).item()
    by_phase = grid.group_by("phase").agg(alt=pl.col("alt_m").median(), vr=pl.col("vertical_rate_mps").median())
    alt = dict(by_phase.select("phase", "alt").rows())
    vr = dict(by_phase.select("phase", "vr").rows())
    assert alt["cruise"] > 9000 > max(alt["climb"], alt["descent"])
    assert vr["climb"] > 3 and vr["descent"] < -3 and abs(vr["cruise"]) < 1
    table = phase_table(grid)
    assert set(table["phase"]) == set(PHASES)
    assert (table["start_ts"] <= table["end_ts"]).all()


@pytest.mark.parametrize("method", ["vertical", "regions"])
def test_each_flights_phases_are_those_it_gets_alone(cleaned, method):
    """The phases look at one flight's rows only (differences, first times and first hits within the flight): a flight
    among all the others is phased as it is alone (the route's median duration comes from the flights table, whole in
    both). The climb ends at half the route's duration at the
    earliest, so that the time elapsed since the flight's first point decides where."""
    tracks, flights = cleaned
    cfg = PhaseConfig(method=method, climb_end_fraction=0.5)
    grid = resample(tracks)
    among_all = assign_phases(grid, flights, cfg, airports_table())
    ids = grid["flight_id"].unique().sort()
    for fid in ids.gather([0, 1, len(ids) // 2, len(ids) - 1]):
        alone = assign_phases(grid.filter(pl.col("flight_id") == fid), flights, cfg, airports_table())
        assert alone.equals(among_all.filter(pl.col("flight_id") == fid)), fid
        assert alone["phase"].n_unique() >= 2


def test_unknown_phase_method(cleaned):
    tracks, flights = cleaned
    with pytest.raises(ValueError, match="unknown phase method"):
        assign_phases(resample(tracks), flights, PhaseConfig(method="magic"))


@pytest.mark.parametrize("dt_s", [0, -5, 1e-9])
def test_resample_refuses_a_step_that_is_not_positive(cleaned, dt_s):
    with pytest.raises(ValueError, match="dt_s must be a positive step"):
        resample(cleaned[0], dt_s)


def test_exact_step_check_fails_with_a_reason_on_tracks_without_steps(cleaned):
    from assets.aviation.checks import tracks_exact_step
    from warehouse.storage import write_table

    grid = resample(cleaned[0]).head(0)  # no step anywhere (e.g. every flight shorter than one step)
    write_table("tracks_20s", grid.with_columns(temperature_k=pl.lit(0.0), wind_u_mps=pl.lit(0.0), wind_v_mps=pl.lit(0.0), phase=pl.lit("")))
    result = tracks_exact_step()
    assert not result.passed and "no step" in result.metadata["why"].text


def test_resample_is_vectorised_over_flights(cleaned):
    """Doubling the flights (time-shifted copies) gives exactly the same points for the originals."""
    tracks, _ = cleaned
    shifted = tracks.with_columns(flight_id=pl.col("flight_id") + "_copy", ts=pl.col("ts") + pl.duration(days=30), lat=pl.col("lat") + 0.5)
    both = resample(pl.concat([tracks, shifted]))
    alone = resample(tracks)
    np.testing.assert_allclose(both.filter(~pl.col("flight_id").str.ends_with("_copy"))["lat"].to_numpy(), alone["lat"].to_numpy())


def test_resample_with_missing_values_equals_np_interp_per_flight():
    """A column with missing values (leading, trailing, inside, all of a flight, all but one) interpolates each
    flight's valid values with np.interp and leaves gaps outside the first/last valid one (altitude: the rates
    would be derived from the positions where missing)."""
    rng = np.random.default_rng(4)
    frames = []
    for f in range(40):
        n = int(rng.integers(1, 60))
        t = np.sort(rng.choice(np.arange(0, 3_000), n, replace=False)) * 1_000_000 + f * 1_000_000_000
        v = rng.normal(100.0, 20.0, n)
        kind = f % 5
        if kind == 1:
            v[: n // 3] = np.nan
        elif kind == 2:
            v[n - n // 3 :] = np.nan
        elif kind == 3:
            v[rng.random(n) < 0.5] = np.nan
        elif kind == 4:
            v[:] = np.nan
            v[rng.integers(0, n)] = 1.0 if f % 10 == 4 else np.nan
        frames.append(pl.DataFrame({"flight_id": f"f{f:02d}", "ts": pl.Series(t).cast(pl.Datetime("us", "UTC")), "v": v}))
    tracks = pl.concat(frames).with_columns(
        lat=pl.lit(54.0), lon=pl.lit(20.0), alt_m=pl.col("v"), groundspeed_mps=pl.lit(200.0), track_deg=pl.lit(90.0),
        vertical_rate_mps=pl.lit(0.0),
    )
    grid = resample(tracks.drop("v"), dt_s=20.0)
    for (fid,), g in grid.group_by("flight_id"):
        src = tracks.filter(pl.col("flight_id") == fid)
        t, v = src["ts"].dt.epoch("us").to_numpy().astype(float), src["v"].to_numpy()
        x = g["ts"].dt.epoch("us").to_numpy().astype(float)
        ok = ~np.isnan(v)
        want = np.full(len(x), np.nan)
        if ok.any():
            want = np.interp(x, t[ok], v[ok])
            want[(x < t[ok][0]) | (x > t[ok][-1])] = np.nan
        np.testing.assert_array_equal(g["alt_m"].to_numpy(), want)


def test_resample_leaves_gaps_outside_the_valid_values_of_the_first_and_last_flight():
    """Before the first flight's first valid value the search among the valid rows finds a later row of the same
    flight, and after the last flight's last valid value there is no valid row after it at all: both are gaps, not
    extrapolations (the per-flight test above has neither case: its first flight has no missing value and its last
    none valid)."""
    t = pl.Series(np.arange(0, 300, 20) * 1_000_000).cast(pl.Datetime("us", "UTC"))
    alt = [None, None, None, *np.linspace(9000.0, 9600.0, 10), None, None]
    tracks = pl.DataFrame({"flight_id": ["a"] * 15 + ["b"] * 15, "ts": pl.concat([t, t]), "alt_m": alt[::-1] + alt}).with_columns(
        lat=pl.lit(54.0), lon=pl.lit(20.0), groundspeed_mps=pl.lit(200.0), track_deg=pl.lit(90.0), vertical_rate_mps=pl.lit(0.0))
    grid = resample(tracks, dt_s=20.0)
    for fid, want in (("a", alt[::-1]), ("b", alt)):
        got = grid.filter(pl.col("flight_id") == fid)["alt_m"].to_numpy()
        np.testing.assert_array_equal(got, np.array(want, dtype=float))
