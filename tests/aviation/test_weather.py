"""Weather reading, ISA and trajectory sampling, on the real compact copies in data/weather/."""

from __future__ import annotations

import datetime as dt
import subprocess
import sys
from pathlib import Path

import numpy as np
import polars as pl
import pytest

from models.aviation.weather import (
    ALIGNMENTS,
    WEATHER_SCHEMA,
    WeatherError,
    align_times,
    isa_altitude_m,
    isa_pressure_hpa,
    read_weather,
    sample_weather,
    share_outside_levels,
    weather_time_range,
)

DATA = Path(__file__).resolve().parents[2] / "data" / "weather"
GFS = DATA / "gfs_2011_isobaric_t_u_v.grib2"
ERA5 = DATA / "era5_2019-01-05_europe_200-300hPa.nc"
UTC = dt.UTC


@pytest.fixture(scope="module")
def gfs() -> pl.DataFrame:
    return read_weather(GFS)


@pytest.fixture(scope="module")
def era5() -> pl.DataFrame:
    return read_weather(ERA5)


def us(text: str | list[str]) -> np.ndarray:
    return np.atleast_1d(np.array(text, dtype="datetime64[us]"))


def node(frame: pl.DataFrame, time: str, level: float, lat: float, lon: float) -> pl.DataFrame:
    """The one grid row at (time, level, lat, lon)."""
    t = dt.datetime.fromisoformat(time).replace(tzinfo=UTC)
    row = frame.filter(
        (pl.col("time") == t) & (pl.col("level_hpa") == level) & (pl.col("lat") == lat) & (pl.col("lon") == lon)
    )
    assert row.height == 1, (time, level, lat, lon)
    return row


def sample_one(frame, time, level, lat, lon, alignment="exact"):
    alt = isa_altitude_m(np.array([level], float))
    out = sample_weather(frame, us(time), np.array([lat], float), np.array([lon], float), alt, alignment)
    return {k: v[0] for k, v in out.items()}


def assert_plausible(frame: pl.DataFrame) -> None:
    assert frame.schema == pl.Schema(WEATHER_SCHEMA)
    assert frame.null_count().sum_horizontal().item() == 0
    assert frame.equals(frame.sort(["time", "level_hpa", "lat", "lon"]))
    assert frame["lon"].min() >= -180 and frame["lon"].max() < 180
    # Airliner levels (150 hPa and below, i.e. under ~13.6 km) hold 190..320 K.
    flight = frame.filter(pl.col("level_hpa") >= 150)
    assert 190 < flight["temperature_k"].min() and flight["temperature_k"].max() < 320
    # The tropical tropopause is colder: GFS has 186.6 K at 100 hPa over the western Pacific.
    assert 180 < frame["temperature_k"].min()
    for column in ("wind_u_mps", "wind_v_mps"):
        assert frame[column].abs().max() < 150
    sizes = [frame[c].n_unique() for c in ("time", "level_hpa", "lat", "lon")]
    assert frame.height == int(np.prod(sizes))  # a complete grid, no duplicates


# --- reading -------------------------------------------------------------------------------


def test_read_gfs_copy(gfs):
    assert_plausible(gfs)
    assert weather_time_range(gfs) == (dt.datetime(2011, 1, 15, 12, tzinfo=UTC),) * 2  # run 10th 12z + 120 h
    levels = gfs["level_hpa"].unique().sort().to_list()
    assert len(levels) >= 20 and levels[0] == 10 and levels[-1] == 1000 and 250 in levels
    assert gfs["lat"].n_unique() == 73 and gfs["lon"].n_unique() == 144  # global 2.5°


def test_a_grib1_file_is_read_as_grib(tmp_path):
    """GRIB 1 has its edition byte where GRIB 2 has it (octet 8, after a 3-byte length): eccodes' GRIB 1 sample, a
    geopotential field, reaches the GRIB reader, which names what it found, whatever the file's extension."""
    eccodes = pytest.importorskip("eccodes")
    h = eccodes.codes_grib_new_from_samples("GRIB1")
    try:
        with open(tmp_path / "sample.dat", "wb") as f:
            eccodes.codes_write(h, f)
    finally:
        eccodes.codes_release(h)
    raises_one_line(read_weather, tmp_path / "sample.dat", match=r"found isobaric GRIB short names \['z'\]")


def test_gfs_values_match_raw_grib():
    """Check the reader's orientation (north->south rows, 0..360 columns) against eccodes itself."""
    eccodes = pytest.importorskip("eccodes")
    eccodes.codes_grib_multi_support_on()  # NCEP packs u and v in one message
    raw = {}
    try:
        with open(GFS, "rb") as f:
            while (h := eccodes.codes_grib_new_from_file(f)) is not None:
                if eccodes.codes_get(h, "level") == 250:
                    raw[eccodes.codes_get(h, "shortName")] = eccodes.codes_get_values(h).reshape(73, 144)
                eccodes.codes_release(h)
    finally:
        eccodes.codes_grib_multi_support_off()
    frame = read_weather(GFS, bbox=(45, 55, -15, 15))
    j = 16  # rows run north to south: 50°N is row (90 - 50) / 2.5
    for lon, col in ((10.0, 4), (-10.0, 140)):  # columns run 0..357.5: -10° is 350° / 2.5 = 140
        got = node(frame, "2011-01-15T12:00", 250, 50.0, lon)
        assert got["temperature_k"].item() == pytest.approx(raw["t"][j, col])
        assert got["wind_u_mps"].item() == pytest.approx(raw["u"][j, col])
        assert got["wind_v_mps"].item() == pytest.approx(raw["v"][j, col])


def test_read_era5_copy(era5):
    assert_plausible(era5)
    start, end = weather_time_range(era5)
    assert (start, end) == (dt.datetime(2019, 1, 5, 1, tzinfo=UTC), dt.datetime(2019, 1, 5, 10, tzinfo=UTC))
    assert era5["time"].n_unique() == 10
    assert era5["level_hpa"].unique().sort().to_list() == [200.0, 225.0, 300.0]
    assert (era5["lat"].min(), era5["lat"].max(), era5["lon"].min(), era5["lon"].max()) == (40, 70, 0, 50)


def test_era5_values_match_xarray(era5):
    """The file stores (longitude, latitude, level, time): check the transposition."""
    xr = pytest.importorskip("xarray")
    with xr.open_dataset(ERA5, engine="h5netcdf") as ds:
        raw = ds.sel(longitude=24.0, latitude=60.0, level=225, time="2019-01-05T07:00")
        expected = [float(raw[v]) for v in ("air_temperature", "eastward_wind", "northward_wind")]
    got = node(era5, "2019-01-05T07:00", 225, 60.0, 24.0)
    assert got.select("temperature_k", "wind_u_mps", "wind_v_mps").row(0) == pytest.approx(expected)


def test_bbox_crop(era5):
    box = read_weather(ERA5, bbox=(50, 60, 10, 20))
    assert (box["lat"].min(), box["lat"].max(), box["lon"].min(), box["lon"].max()) == (50, 60, 10, 20)
    assert box.equals(era5.filter(pl.col("lat").is_between(50, 60), pl.col("lon").is_between(10, 20)))
    with pytest.raises(WeatherError, match="selects no grid point"):
        read_weather(ERA5, bbox=(-10, 0, 10, 20))
    with pytest.raises(WeatherError, match="bbox"):
        read_weather(ERA5, bbox=(60, 50, 10, 20))


def test_netcdf_name_variants(tmp_path):
    """New-CDS ERA5 names (valid_time, pressure_level), 0..360 longitudes, NetCDF3, Pa levels."""
    xr = pytest.importorskip("xarray")
    lon = np.array([0.0, 90.0, 180.0, 270.0])
    lat = np.array([10.0, 0.0])  # north -> south, as ERA5 stores it
    shape = (1, 2, 2, 4)
    values = np.arange(np.prod(shape), dtype=float).reshape(shape)
    ds = xr.Dataset(
        {name: (("valid_time", "pressure_level", "latitude", "longitude"), values + k) for k, name in enumerate("tuv")},
        coords={
            "valid_time": np.array(["2024-06-01T12:00"], dtype="datetime64[ns]"),
            "pressure_level": [300.0, 200.0],
            "latitude": lat,
            "longitude": lon,
        },
    )
    ds.to_netcdf(tmp_path / "new_cds.nc", engine="scipy")  # classic NetCDF3: read with scipy
    frame = read_weather(tmp_path / "new_cds.nc")
    assert frame.schema == pl.Schema(WEATHER_SCHEMA)
    assert frame["lon"].unique().sort().to_list() == [-180.0, -90.0, 0.0, 90.0]
    assert frame.equals(frame.sort(["time", "level_hpa", "lat", "lon"]))
    got = node(frame, "2024-06-01T12:00", 200.0, 10.0, -90.0)  # level index 1, lat index 0, lon 270 = index 3
    assert got["temperature_k"].item() == values[0, 1, 0, 3]
    assert got["wind_v_mps"].item() == values[0, 1, 0, 3] + 2

    # CMIP-style: `plev` in Pa, plain `time`, `lat`/`lon`.
    cmip = ds.rename(valid_time="time", pressure_level="plev", latitude="lat", longitude="lon")
    cmip = cmip.assign_coords(plev=("plev", [30000.0, 20000.0], {"units": "Pa"}))
    cmip.to_netcdf(tmp_path / "cmip.nc", engine="scipy")
    assert read_weather(tmp_path / "cmip.nc")["level_hpa"].unique().sort().to_list() == [200.0, 300.0]


# --- ISA -------------------------------------------------------------------------------------


def test_isa_pressure():
    p = isa_pressure_hpa(np.array([0.0, 11_000.0, 20_000.0]))
    assert p[0] == pytest.approx(1013.25, abs=1e-9)
    assert p[1] == pytest.approx(226.32, abs=0.05)
    assert p[2] == pytest.approx(54.75, abs=0.05)
    alt = np.linspace(-500, 20_000, 1001)
    p = isa_pressure_hpa(alt)
    assert p.shape == alt.shape and np.all(np.diff(p) < 0)
    assert isa_altitude_m(p) == pytest.approx(alt, abs=1e-6)
    assert isa_altitude_m(np.array([250.0]))[0] == pytest.approx(10_363, abs=1)  # ≈ FL340
    assert np.isnan(isa_pressure_hpa(np.array([np.nan]))[0])


# --- sampling --------------------------------------------------------------------------------


def test_sample_at_grid_node_equals_grid_value(era5):
    got = sample_one(era5, "2019-01-05T04:00", 225.0, 56.0, 12.0)
    row = node(era5, "2019-01-05T04:00", 225.0, 56.0, 12.0)
    for column, value in got.items():
        assert value == pytest.approx(row[column].item(), rel=1e-12)


def test_sample_midpoint_is_bilinear_mean(era5):
    got = sample_one(era5, "2019-01-05T04:00", 225.0, 57.0, 13.0)  # centre of a 2° cell
    corners = pl.concat([node(era5, "2019-01-05T04:00", 225.0, la, lo) for la in (56.0, 58.0) for lo in (12.0, 14.0)])
    for column, value in got.items():
        assert value == pytest.approx(corners[column].mean(), rel=1e-12)


def test_sample_time_and_level_interpolation(era5):
    # Half-way in time -> mean of the two hours.
    got = sample_one(era5, "2019-01-05T04:30", 225.0, 56.0, 12.0)
    hours = pl.concat([node(era5, t, 225.0, 56.0, 12.0) for t in ("2019-01-05T04:00", "2019-01-05T05:00")])
    assert got["temperature_k"] == pytest.approx(hours["temperature_k"].mean(), rel=1e-12)
    # Half-way in log-pressure between 200 and 225 hPa -> mean of the two levels.
    got = sample_one(era5, "2019-01-05T04:00", float(np.sqrt(200 * 225)), 56.0, 12.0)
    levels = pl.concat([node(era5, "2019-01-05T04:00", p, 56.0, 12.0) for p in (200.0, 225.0)])
    assert got["wind_u_mps"] == pytest.approx(levels["wind_u_mps"].mean(), rel=1e-12)


def test_sample_clamps_levels_and_nans_outside_grid(era5):
    ts = us(["2019-01-05T04:00"] * 4)
    out = sample_weather(
        era5, ts, np.array([56.0, 56.0, 80.0, 56.0]), np.array([12.0, 12.0, 12.0, 60.0]),
        np.array([0.0, 30_000.0, 10_000.0, 10_000.0]),
    )  # fmt: skip
    t = out["temperature_k"]
    assert t[0] == pytest.approx(node(era5, "2019-01-05T04:00", 300.0, 56.0, 12.0)["temperature_k"].item())
    assert t[1] == pytest.approx(node(era5, "2019-01-05T04:00", 200.0, 56.0, 12.0)["temperature_k"].item())
    assert np.isnan(t[2]) and np.isnan(t[3])  # outside the European box
    # Missing inputs give NaN, never a made-up value.
    ts = np.array(["2019-01-05T04:00", "2019-01-05T04:00", "2019-01-05T04:00", "NaT"], dtype="datetime64[us]")
    nan = np.nan
    out = sample_weather(era5, ts, np.array([nan, 56, 56, 56]), np.array([12, nan, 12, 12]), np.array([1e4, 1e4, nan, 1e4]))
    assert np.isnan(out["wind_u_mps"]).all()


def test_share_outside_levels(era5, gfs):
    alt = np.array([1_000.0, 9_500.0, 10_000.0, 12_000.0])  # 899, 294, 265, 194 hPa
    assert share_outside_levels(era5, alt) == 0.5  # 200-300 hPa: the 1 km and 12 km points are clamped
    assert share_outside_levels(gfs, alt) == 0.0


def test_sample_longitude_wraps_on_global_grid(gfs):
    level, lat = 250.0, 50.0
    t = "2011-01-15T12:00"
    east, west = (node(gfs, t, level, lat, lo)["temperature_k"].item() for lo in (177.5, -180.0))
    lons = np.array([178.75, -181.25, 538.75, 10.0, 370.0, -350.0, 357.5, -2.5])
    alt = isa_altitude_m(np.full(lons.size, level))
    out = sample_weather(gfs, us([t] * lons.size), np.full(lons.size, lat), lons, alt)
    temp = out["temperature_k"]
    assert temp[0] == pytest.approx((east + west) / 2, rel=1e-12)  # across the antimeridian
    assert temp[1] == pytest.approx(temp[0]) and temp[2] == pytest.approx(temp[0])
    assert temp[3] == pytest.approx(temp[4]) == pytest.approx(temp[5])
    assert temp[6] == pytest.approx(temp[7]) == pytest.approx(node(gfs, t, level, lat, -2.5)["temperature_k"].item())


def test_time_of_day_alignment(era5):
    assert ALIGNMENTS == ("exact", "time_of_day")
    lat, lon, alt = np.full(3, 56.0), np.full(3, 12.0), isa_altitude_m(np.full(3, 225.0))
    flights = us(["2022-03-01T06:30", "2022-03-01T23:00", "2022-03-02T00:30"])
    stand_in = us(["2019-01-05T06:30", "2019-01-05T10:00", "2019-01-05T01:00"])  # clamped into 01:00..10:00
    shifted = sample_weather(era5, flights, lat, lon, alt, alignment="time_of_day")
    direct = sample_weather(era5, stand_in, lat, lon, alt, alignment="exact")
    for column in shifted:
        np.testing.assert_allclose(shifted[column], direct[column], rtol=1e-12)
    # A polars Series in another time zone gives the same answer (times are converted to UTC).
    paris = pl.Series(flights).dt.replace_time_zone("UTC").dt.convert_time_zone("Europe/Paris")
    again = sample_weather(era5, paris, lat, lon, alt, alignment="time_of_day")
    np.testing.assert_allclose(again["temperature_k"], shifted["temperature_k"], rtol=1e-12)
    # align_times works on µs and keeps NaT.
    nat = np.iinfo(np.int64).min
    weather_us = us(["2019-01-05T01:00", "2019-01-05T10:00"]).view(np.int64)
    aligned = align_times(np.array([us("2022-03-01T06:30").view(np.int64)[0], nat]), weather_us, "time_of_day")
    assert aligned[0] == us("2019-01-05T06:30").view(np.int64)[0] and aligned[1] == nat


def test_exact_alignment_outside_range_raises(era5, gfs):
    args = (np.array([56.0]), np.array([12.0]), np.array([10_000.0]))
    with pytest.raises(WeatherError, match="time_of_day") as err:
        sample_weather(era5, us(["2022-03-01T06:30"]), *args)
    message = str(err.value)
    assert "\n" not in message and "2022-03-01" in message and "2019-01-05" in message
    # Single-time weather (one GFS forecast) is exact only at its valid time.
    assert np.isfinite(sample_weather(gfs, us(["2011-01-15T12:00"]), *args)["wind_u_mps"]).all()
    with pytest.raises(WeatherError, match="outside the weather time range"):
        sample_weather(gfs, us(["2011-01-15T12:01"]), *args)
    out = sample_weather(gfs, us(["2022-03-01T06:30"]), *args, alignment="time_of_day")
    assert np.isfinite(out["temperature_k"]).all()


def test_sample_is_vectorised_and_fast(era5):
    import time

    rng = np.random.default_rng(0)
    n = 200_000
    ts = us("2019-01-05T01:00") + rng.integers(0, 9 * 3600 * 10**6, n).astype("timedelta64[us]")
    start = time.perf_counter()
    out = sample_weather(era5, ts, rng.uniform(40, 70, n), rng.uniform(0, 50, n), rng.uniform(8000, 13000, n))
    assert time.perf_counter() - start < 2.0  # ~0.15 s here; generous for slow CI
    assert all(v.shape == (n,) and np.isfinite(v).all() for v in out.values())


# --- errors: always WeatherError, always one line -----------------------------------------


def raises_one_line(func, *args, match: str, **kwargs) -> str:
    with pytest.raises(WeatherError, match=match) as err:
        func(*args, **kwargs)
    message = str(err.value)
    assert "\n" not in message and message
    return message


def test_bad_files(tmp_path):
    raises_one_line(read_weather, tmp_path / "missing.nc", match="not found")

    (tmp_path / "notes.txt").write_text("wind 20 kt\n")
    raises_one_line(read_weather, tmp_path / "notes.txt", match="unsupported weather file type '.txt'")

    csv = tmp_path / "table.nc"
    csv.write_text("time,lat,lon,t\n2019-01-05,50,10,220\n")
    message = raises_one_line(read_weather, csv, match="table.nc")
    assert "NetCDF" in message

    fake = tmp_path / "broken.grib2"
    fake.write_bytes(b"GRIB" + bytes(3) + b"\x02" + bytes(200))  # a GRIB 2 indicator, then nothing valid
    raises_one_line(read_weather, fake, match="cannot read .*broken.grib2 as grib")

    # text that mentions GRIB is not GRIB (it used to reach cfgrib, which logs a traceback per "message")
    notes = tmp_path / "notes.grib2"
    notes.write_text("# how the GRIB files were cropped\n" * 20)
    raises_one_line(read_weather, notes, match="extension says GRIB but the content is not")

    bad_hdf = tmp_path / "broken.nc"
    bad_hdf.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(200))
    raises_one_line(read_weather, bad_hdf, match="cannot read .*broken.nc")


def test_duplicate_coordinates_are_one_line(tmp_path):
    """A long axis with repeated values is named by its first repeats, not printed whole over many lines."""
    xr = pytest.importorskip("xarray")
    lat = np.repeat(np.arange(100.0) / 2, 2)  # 200 latitudes, each twice
    ds = xr.Dataset(
        {k: (("time", "level", "latitude", "longitude"), np.full((1, 1, lat.size, 2), 220.0)) for k in ("t", "u", "v")},
        coords={"time": np.array(["2019-01-05"], "datetime64[ns]"), "level": [250.0], "latitude": lat, "longitude": [0.0, 1.0]},
    )
    ds.to_netcdf(tmp_path / "dup.nc", engine="scipy")
    message = raises_one_line(read_weather, tmp_path / "dup.nc", match="duplicate latitude values: 0.0, 0.5, 1.0 and 97 more")
    assert len(message) < 200


def test_missing_variables(tmp_path):
    xr = pytest.importorskip("xarray")
    ds = xr.Dataset(
        {"t": (("time", "level", "latitude", "longitude"), np.full((1, 1, 2, 2), 220.0))},
        coords={
            "time": np.array(["2019-01-05"], "datetime64[ns]"),
            "level": [250.0],
            "latitude": [0.0, 1.0],
            "longitude": [0.0, 1.0],
        },
    )
    ds.to_netcdf(tmp_path / "t_only.nc", engine="scipy")
    message = raises_one_line(read_weather, tmp_path / "t_only.nc", match="missing wind_u_mps")
    assert "wind_v_mps" in message and "found variables ['t']" in message

    # A GRIB file with only the temperature messages of the shipped copy.
    eccodes = pytest.importorskip("eccodes")
    with open(GFS, "rb") as src, open(tmp_path / "t_only.grib2", "wb") as dst:
        while (h := eccodes.codes_grib_new_from_file(src)) is not None:
            if eccodes.codes_get(h, "shortName") == "t":
                eccodes.codes_write(h, dst)
            eccodes.codes_release(h)
    message = raises_one_line(read_weather, tmp_path / "t_only.grib2", match="missing wind_u_mps")
    assert "['t']" in message


def test_unrecognised_coordinates(tmp_path):
    xr = pytest.importorskip("xarray")
    grid = np.full((1, 2, 2), 220.0)
    ds = xr.Dataset(
        {v: (("time", "y", "x"), grid) for v in "tuv"},
        coords={"time": np.array(["2019-01-05"], "datetime64[ns]"), "y": [0.0, 1.0], "x": [0.0, 1.0]},
    )
    ds.to_netcdf(tmp_path / "xy.nc", engine="scipy")
    message = raises_one_line(read_weather, tmp_path / "xy.nc", match="unrecognised coordinates")
    assert "latitude" in message and "pressure level" in message

    no_time = ds.rename(y="latitude", x="longitude").drop_vars("time").isel(time=0).expand_dims(level=[250.0])
    no_time.to_netcdf(tmp_path / "no_time.nc", engine="scipy")
    raises_one_line(read_weather, tmp_path / "no_time.nc", match="no time coordinate")


def test_bad_sampling_requests(era5):
    one = np.array([50.0])
    raises_one_line(sample_weather, era5, us("2019-01-05T02:00"), one, one, one, alignment="nearest", match="alignment")
    raises_one_line(sample_weather, era5, us(["2019-01-05T02:00"] * 2), one, one, one, match="same length")
    raises_one_line(sample_weather, era5, np.array([1.0]), one, one, one, match="datetime64")
    raises_one_line(sample_weather, era5.head(100), us("2019-01-05T02:00"), one, one, one, match="complete")
    raises_one_line(sample_weather, era5.drop("wind_v_mps"), us("2019-01-05T02:00"), one, one, one, match="wind_v_mps")
    raises_one_line(weather_time_range, era5.head(0), match="empty")


def test_grib_reader_then_libsumo_in_one_process_exits_cleanly():
    """eccodes' bundled libraries loaded before libsumo used to crash the process at exit (double free),
    e.g. a test session or a Dagster run that reads GRIB weather and then simulates urban traffic."""
    repo = DATA.parents[1]
    code = (
        "from models.aviation.weather import read_weather\n"
        f"read_weather({str(GFS)!r})\n"
        "import libsumo\n"
        f"libsumo.start(['sumo', '-n', {str(repo / 'data' / 'sumo' / 'bologna_acosta.net.xml.gz')!r}, '--no-step-log'])\n"
        "libsumo.simulationStep()\n"
        "libsumo.close()\n"
    )
    done = subprocess.run([sys.executable, "-c", code], cwd=repo, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, f"exit {done.returncode}: {done.stderr[-500:]}"


def test_reading_weather_prints_nothing_of_libsumo():
    code = "from models.aviation.weather import read_weather; read_weather('data/weather/era5_2019-01-05_europe_200-300hPa.nc')"
    run = subprocess.run([sys.executable, "-c", code], cwd=DATA.parents[1], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and run.stdout == ""
