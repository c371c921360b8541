"""Weather on pressure levels: read it, and sample it along flight trajectories.

What this module is for
-----------------------
Aircraft performance depends on the air they fly through: the wind adds to or
subtracts from the ground speed, and the temperature sets the speed of sound
(and so the Mach number).  Numerical weather models (GFS, ERA5, ...) publish
these fields on a grid of *pressure levels* (e.g. 250 hPa ~ 10.4 km), not on
altitudes, so sampling them for a flight takes three steps:

1. ``read_weather``: read a GRIB2 or NetCDF file into one tidy polars table,
   one row per time x pressure level x latitude x longitude.
2. ``isa_pressure_hpa``: turn each aircraft altitude into a pressure with the
   International Standard Atmosphere (ISA), so we know which levels bracket it.
3. ``sample_weather``: interpolate the grid at every (time, pressure, lat, lon)
   point of the trajectories, all points at once.

Everything here is a pure function of its inputs (no Dagster, no I/O other than
``read_weather`` reading its file), so the pipeline assets stay thin wrappers.

Time alignment
--------------
The sample weather shipped with the project is NOT from the same dates as the
sample flights.  Silently using "the nearest weather" would make wrong wind
look like real wind, so ``sample_weather`` makes the choice explicit with
``alignment`` (see ``ALIGNMENTS`` and ``align_times``).

Errors
------
Every problem with the input raises ``WeatherError`` (a ``ValueError``) with a
single-line message that names the file or the ranges involved.
"""

from __future__ import annotations

import datetime as dt
import re
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import polars as pl

__all__ = [
    "ALIGNMENTS",
    "WEATHER_SCHEMA",
    "WeatherError",
    "align_times",
    "isa_altitude_m",
    "isa_pressure_hpa",
    "read_weather",
    "sample_weather",
    "weather_time_range",
]


class WeatherError(ValueError):
    """A weather file or a weather request cannot be used; the message is one line."""

    def __init__(self, message: str) -> None:
        # Collapse newlines/indentation coming from wrapped library errors, so logs
        # and Dagster's UI show one readable line; cap the length for the same reason.
        text = " ".join(str(message).split())
        if len(text) > 600:
            text = text[:597] + "..."
        super().__init__(text)


# The table read_weather returns.  Sampling relies on these names and types.
WEATHER_SCHEMA: dict[str, pl.DataType] = {
    "time": pl.Datetime("us", "UTC"),
    "level_hpa": pl.Float64(),
    "lat": pl.Float64(),
    "lon": pl.Float64(),
    "temperature_k": pl.Float64(),
    "wind_u_mps": pl.Float64(),
    "wind_v_mps": pl.Float64(),
}
_VALUE_COLUMNS = ("temperature_k", "wind_u_mps", "wind_v_mps")
_KEY_COLUMNS = ("time", "level_hpa", "lat", "lon")

# --------------------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------------------

_NETCDF_SUFFIXES = {".nc", ".nc4", ".netcdf", ".cdf"}
_GRIB_SUFFIXES = {".grib", ".grib2", ".grb", ".grb2", ".grib1", ".grb1"}

# Names differ between producers: ERA5 from the CDS uses short names (t/u/v), files
# written by tools such as pycontrails use CF standard names, cfgrib uses GRIB short
# names.  We also accept any variable whose `standard_name` attribute matches.
_VARIABLES = {
    "temperature_k": (("t", "air_temperature", "temperature", "ta", "T"), "air_temperature"),
    "wind_u_mps": (("u", "eastward_wind", "ua", "U"), "eastward_wind"),
    "wind_v_mps": (("v", "northward_wind", "va", "V"), "northward_wind"),
}
_LAT_NAMES = ("latitude", "lat")
_LON_NAMES = ("longitude", "lon")
# ERA5 old CDS: `level`; ERA5 new CDS: `pressure_level`; cfgrib: `isobaricInhPa`;
# CMIP-style: `plev` (in Pa, converted below).
_LEVEL_NAMES = ("level", "pressure_level", "isobaricInhPa", "plev", "lev", "pressure")


def read_weather(
    path: str | Path,
    bbox: tuple[float, float, float, float] | None = None,
) -> pl.DataFrame:
    """Read temperature and wind on pressure levels from a GRIB or NetCDF file.

    Returns a polars DataFrame with columns (see ``WEATHER_SCHEMA``)::

        time (Datetime us UTC), level_hpa, lat, lon (-180..180),
        temperature_k, wind_u_mps, wind_v_mps            (all Float64)

    with one row per time x level x lat x lon, sorted by those four columns.
    ``time`` is the *valid* time (analysis time + forecast step for forecasts).

    The format is detected from the file's first bytes ("GRIB", HDF5 or classic
    NetCDF signature), never from its name: a file with neither signature is
    refused, the message saying whether its extension promised GRIB or NetCDF.
    GRIB files are read with cfgrib, keeping only isobaric t/u/v messages; NetCDF4
    files with h5netcdf (which needs h5py), classic NetCDF3 files with scipy.

    ``bbox=(lat_min, lat_max, lon_min, lon_max)`` keeps only grid points inside the
    box (inclusive, longitudes in -180..180; ``lon_min > lon_max`` means a box across
    the antimeridian).  Cropping happens before the values are loaded, so it also
    limits memory.

    Raises WeatherError (one line) when the file is missing, is not a readable GRIB
    or NetCDF file, lacks temperature or wind, or has coordinates we do not know.
    """
    path = Path(path)
    if not path.exists():
        raise WeatherError(f"weather file not found: {path}")
    if not path.is_file():
        raise WeatherError(f"weather path is not a file: {path}")
    if bbox is not None:
        bbox = _check_bbox(bbox)

    kind = _detect_format(path)
    ds = _open_dataset(path, kind)
    try:
        return _dataset_to_frame(ds, path, kind, bbox)
    finally:
        ds.close()


def _check_bbox(bbox: Sequence[float]) -> tuple[float, float, float, float]:
    try:
        lat_min, lat_max, lon_min, lon_max = (float(v) for v in bbox)
    except (TypeError, ValueError) as exc:
        raise WeatherError(f"bbox must be (lat_min, lat_max, lon_min, lon_max), got {bbox!r}") from exc
    if not (-90 <= lat_min <= lat_max <= 90):
        raise WeatherError(f"bbox latitudes must satisfy -90 <= lat_min <= lat_max <= 90, got {bbox!r}")
    if not (-180 <= lon_min <= 180 and -180 <= lon_max <= 180):
        raise WeatherError(f"bbox longitudes must lie in -180..180, got {bbox!r}")
    return lat_min, lat_max, lon_min, lon_max


def _detect_format(path: Path) -> str:
    """Return "grib", "netcdf4" (HDF5 based) or "netcdf3" from content, then extension."""
    with open(path, "rb") as f:
        head = f.read(4096)
    suffix = path.suffix.lower()
    # Content first: a file's signature does not lie, its name might.
    if head.startswith(b"\x89HDF\r\n\x1a\n"):
        return "netcdf4"
    if head.startswith(b"CDF\x01") or head.startswith(b"CDF\x02") or head.startswith(b"CDF\x05"):
        return "netcdf3"
    # "GRIB" then the edition (1 or 2) in the message's 8th byte; a short WMO bulletin header may come first. The
    # edition byte tells a GRIB file from text that merely mentions GRIB.
    if re.search(rb"GRIB.{3}[\x01\x02]", head, re.DOTALL):
        return "grib"
    if suffix in _NETCDF_SUFFIXES or suffix in _GRIB_SUFFIXES:
        expected = "NetCDF" if suffix in _NETCDF_SUFFIXES else "GRIB"
        raise WeatherError(
            f"cannot read {path}: the extension says {expected} but the content is not "
            f"(it starts with {head[:16]!r})"
        )
    raise WeatherError(
        f"unsupported weather file type {suffix or '(no extension)'!r} for {path}: "
        f"expected GRIB ({', '.join(sorted(_GRIB_SUFFIXES))}) or NetCDF ({', '.join(sorted(_NETCDF_SUFFIXES))})"
    )


def _libsumo_before_eccodes() -> None:
    """eccodes' wheels (loaded by cfgrib, also through xarray's backend discovery) put their bundled C
    libraries (proj, sqlite, krb5, ...) in the global symbol namespace; a libsumo imported after them binds
    to those copies and the process dies at exit with a double free. Imported first, each keeps its own."""
    from models.libsumo_import import import_libsumo

    try:
        import_libsumo()
    except ImportError:  # no urban system installed: nothing to protect
        pass


def _open_dataset(path: Path, kind: str) -> Any:
    _libsumo_before_eccodes()
    import xarray as xr  # imported lazily: reading is the only part that needs it

    if kind == "grib":
        engine = "cfgrib"
        kwargs: dict[str, Any] = {
            "backend_kwargs": {
                # Only temperature and wind on pressure levels: other level types have
                # clashing coordinates and cfgrib would refuse to merge them.
                "filter_by_keys": {"typeOfLevel": "isobaricInhPa", "shortName": ["t", "u", "v"]},
                # Do not write a .idx file next to the data (data folders may be read-only).
                "indexpath": "",
            }
        }
    elif kind == "netcdf4":
        engine = "h5netcdf"
        kwargs = {}
        try:
            import h5py  # noqa: F401  (h5netcdf's reader; without it the error is cryptic)
        except ImportError as exc:
            raise WeatherError(
                f"cannot read {path}: NetCDF4/HDF5 files need the h5py package (pip install h5py)"
            ) from exc
    else:
        engine = "scipy"  # classic NetCDF3 reader that ships with scipy
        kwargs = {}
    try:
        ds = xr.open_dataset(path, engine=engine, **kwargs)
    except Exception as exc:  # any library failure becomes one clear line
        raise WeatherError(f"cannot read {path} as {kind} (engine {engine}): {type(exc).__name__}: {exc}") from exc
    return ds


def _find_variable(ds: Any, names: Sequence[str], standard_name: str) -> str | None:
    for name in names:
        if name in ds.data_vars:
            return name
    for name, var in ds.data_vars.items():
        if var.attrs.get("standard_name") == standard_name:
            return str(name)
    return None


def _find_coord(ds: Any, names: Sequence[str]) -> str | None:
    for name in names:
        if name in ds.coords or name in ds.dims:
            return name
    return None


def _grib_isobaric_names(path: Path) -> list[str]:
    """Short names of the isobaric messages of a GRIB file (for error messages only)."""
    _libsumo_before_eccodes()
    import eccodes

    names: set[str] = set()
    with open(path, "rb") as f:
        while (handle := eccodes.codes_grib_new_from_file(f)) is not None:
            try:
                if eccodes.codes_get(handle, "typeOfLevel") == "isobaricInhPa":
                    names.add(eccodes.codes_get(handle, "shortName"))
            finally:
                eccodes.codes_release(handle)
    return sorted(names)


def _dataset_to_frame(ds: Any, path: Path, kind: str, bbox: tuple[float, float, float, float] | None) -> pl.DataFrame:
    var_names = _value_variables(ds, path, kind)
    lat_name, lon_name, level_name = _grid_coords(ds, path)
    times, time_dim = _valid_times(ds, path)  # analysis time + forecast step for forecasts
    levels = _levels_hpa(ds[level_name])
    level_dim = level_name if level_name in ds.dims else None
    lat, lon, lat_keep, lon_keep = _horizontal_crop(ds, lat_name, lon_name, bbox, path)
    wanted_dims = [d for d in (time_dim, level_dim, lat_name, lon_name) if d is not None]
    expected = (times.size, levels.size, lat.size, lon.size)
    arrays = {
        column: _load_variable(ds[name], wanted_dims, (lat_name, lon_name), (lat_keep, lon_keep), time_dim, level_dim, expected, path)
        for column, name in var_names.items()
    }
    return _grid_frame(times, levels, lat, lon, arrays, path)


def _value_variables(ds: Any, path: Path, kind: str) -> dict[str, str]:
    """Which variables hold temperature and wind: {column: variable name}."""
    var_names: dict[str, str] = {}
    missing = []
    for column, (names, standard_name) in _VARIABLES.items():
        found = _find_variable(ds, names, standard_name)
        if found is None:
            missing.append(f"{column} (one of {'/'.join(names)})")
        else:
            var_names[column] = found
    if missing:
        if kind == "grib":  # we filtered on t/u/v, so list what the file does hold
            try:
                found_list = f"isobaric GRIB short names {_grib_isobaric_names(path)}"
            except Exception:  # the listing is a courtesy; never hide the real error
                found_list = f"variables {sorted(map(str, ds.data_vars))}"
        else:
            found_list = f"variables {sorted(map(str, ds.data_vars))}"
        raise WeatherError(f"{path}: missing {', '.join(missing)}; found {found_list}")
    return var_names


def _grid_coords(ds: Any, path: Path) -> tuple[str, str, str]:
    """Names of the latitude, longitude and pressure-level coordinates (regular 1-D lat/lon only)."""
    lat_name = _find_coord(ds, _LAT_NAMES)
    lon_name = _find_coord(ds, _LON_NAMES)
    level_name = _find_coord(ds, _LEVEL_NAMES)
    unknown = [
        what
        for what, name in (("latitude", lat_name), ("longitude", lon_name), ("pressure level", level_name))
        if name is None
    ]
    if unknown:
        raise WeatherError(
            f"{path}: unrecognised coordinates, no {' / '.join(unknown)} coordinate "
            f"(expected names {_LAT_NAMES + _LON_NAMES + _LEVEL_NAMES}); found coordinates "
            f"{sorted(map(str, ds.coords))} and dimensions {sorted(map(str, ds.dims))}"
        )
    assert lat_name and lon_name and level_name
    for name in (lat_name, lon_name):
        if ds[name].ndim != 1:
            raise WeatherError(
                f"{path}: coordinate {name!r} is {ds[name].ndim}-D; only regular latitude/longitude grids are supported"
            )
    return lat_name, lon_name, level_name


def _levels_hpa(coord: Any) -> np.ndarray:
    """Pressure levels in hPa (CMIP-style `plev` is in Pa)."""
    levels = np.atleast_1d(np.asarray(coord.values, dtype=np.float64))
    units = str(coord.attrs.get("units", "")).strip().lower()
    if units == "pa" or (units == "" and levels.size and np.nanmax(levels) > 2000):
        levels = levels / 100.0
    return levels


def _horizontal_crop(
    ds: Any, lat_name: str, lon_name: str, bbox: tuple[float, float, float, float] | None, path: Path
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(latitudes kept, longitudes kept in [-180, 180), and the masks that keep them): the crop is chosen before any
    value is loaded (memory)."""
    lat = np.asarray(ds[lat_name].values, dtype=np.float64)
    lon = (np.asarray(ds[lon_name].values, dtype=np.float64) + 180.0) % 360.0 - 180.0
    lat_keep = np.ones(lat.size, dtype=bool)
    lon_keep = np.ones(lon.size, dtype=bool)
    if bbox is not None:
        lat_min, lat_max, lon_min, lon_max = bbox
        lat_keep = (lat >= lat_min) & (lat <= lat_max)
        if lon_min <= lon_max:
            lon_keep = (lon >= lon_min) & (lon <= lon_max)
        else:  # box across the antimeridian, e.g. 170 .. -170
            lon_keep = (lon >= lon_min) | (lon <= lon_max)
        if not lat_keep.any() or not lon_keep.any():
            raise WeatherError(
                f"{path}: bbox {bbox} selects no grid point; the grid covers lat "
                f"{lat.min():g}..{lat.max():g}, lon {lon.min():g}..{lon.max():g}"
            )
    # Grids that include both ends (0 and 360, or -180 and 180) repeat a column once
    # longitudes are normalised: keep the first copy only.
    _, first = np.unique(lon, return_index=True)
    unique_mask = np.zeros(lon.size, dtype=bool)
    unique_mask[first] = True
    lon_keep &= unique_mask
    return lat[lat_keep], lon[lon_keep], lat_keep, lon_keep


def _load_variable(
    da: Any, wanted_dims: list[str], horizontal: tuple[str, str], keep: tuple[np.ndarray, np.ndarray],
    time_dim: str | None, level_dim: str | None, expected: tuple[int, ...], path: Path,
) -> np.ndarray:
    """One variable, cropped, as a (time, level, lat, lon) float64 array."""
    name = da.name
    for dim in list(da.dims):
        if dim in wanted_dims:
            continue
        if da.sizes[dim] == 1:
            da = da.isel({dim: 0})  # harmless length-1 extra dimension (ensemble number, expver...)
        else:
            raise WeatherError(
                f"{path}: variable {name!r} has an unexpected dimension {dim!r} of size "
                f"{da.sizes[dim]} (dimensions {tuple(map(str, da.dims))}); select one value first"
            )
    missing_dims = [d for d in horizontal if d not in da.dims]
    if missing_dims:
        raise WeatherError(f"{path}: variable {name!r} lacks dimension(s) {missing_dims}")
    da = da.isel({d: np.flatnonzero(k) for d, k in zip(horizontal, keep)})
    values = np.asarray(da.transpose(*[d for d in wanted_dims if d in da.dims]).values, dtype=np.float64)
    # Add the axes that were scalar coordinates (single time, single level).
    if time_dim is None or time_dim not in da.dims:
        values = values[np.newaxis]
    if level_dim is None or level_dim not in da.dims:
        values = values[:, np.newaxis]
    if values.shape != expected:
        raise WeatherError(f"{path}: variable {name!r} has shape {values.shape}, expected {expected}")
    return values


def _grid_frame(
    times: np.ndarray, levels: np.ndarray, lat: np.ndarray, lon: np.ndarray, arrays: dict[str, np.ndarray], path: Path
) -> pl.DataFrame:
    """The tidy table, one row per grid point, sorted by time, level, lat, lon (every axis sorted first)."""
    it, il, iy, ix = (np.argsort(a, kind="stable") for a in (times, levels, lat, lon))
    times, levels, lat, lon = times[it], levels[il], lat[iy], lon[ix]
    arrays = {column: values[np.ix_(it, il, iy, ix)] for column, values in arrays.items()}
    for what, axis in (("time", times), ("level", levels), ("latitude", lat)):
        repeated = axis[1:][axis[1:] == axis[:-1]]
        if repeated.size:  # named, not printed whole: a long axis would spread the message over many lines
            raise WeatherError(f"{path}: duplicate {what} values: {_few(repeated)}")
    if not (levels > 0).all():
        raise WeatherError(f"{path}: pressure levels must be positive, got {_few(levels[levels <= 0])} hPa")

    nt, nl, ny, nx = times.size, levels.size, lat.size, lon.size
    n = nt * nl * ny * nx
    frame = pl.DataFrame(
        {
            "time": pl.Series("time", np.repeat(times.astype("datetime64[us]"), nl * ny * nx)).dt.replace_time_zone(
                "UTC"
            ),
            "level_hpa": np.tile(np.repeat(levels, ny * nx), nt),
            "lat": np.tile(np.repeat(lat, nx), nt * nl),
            "lon": np.tile(lon, nt * nl * ny),
            **{column: arrays[column].reshape(n) for column in _VALUE_COLUMNS},
        }
    )
    return frame.cast(WEATHER_SCHEMA)  # type: ignore[arg-type]


def _few(values: np.ndarray, n: int = 3) -> str:
    """The first distinct values, for a one-line message."""
    distinct = list(dict.fromkeys(map(str, values)))
    return ", ".join(distinct[:n]) + (f" and {len(distinct) - n} more" if len(distinct) > n else "")


def _valid_times(ds: Any, path: Path) -> tuple[np.ndarray, str | None]:
    """Return (valid times as datetime64[ns] 1-D array, the dimension they lie along or None).

    Handles: ERA5 `time` or `valid_time` dimensions; cfgrib forecasts with scalar
    `time`/`step`/`valid_time`, or a `step` dimension with a 1-D `valid_time`.
    """
    if "valid_time" in ds.coords:
        vt = ds["valid_time"]
    elif "time" in ds.coords:
        vt = ds["time"]
        if "step" in ds.coords and np.issubdtype(ds["step"].dtype, np.timedelta64):
            vt = vt + ds["step"]  # forecast: valid time = analysis time + lead time
    else:
        raise WeatherError(
            f"{path}: unrecognised coordinates, no time coordinate (expected 'time' or 'valid_time'); "
            f"found {sorted(map(str, ds.coords))}"
        )
    if not np.issubdtype(vt.dtype, np.datetime64):
        raise WeatherError(f"{path}: time coordinate has dtype {vt.dtype}, expected decoded datetimes")
    if vt.ndim == 0:
        return np.atleast_1d(np.asarray(vt.values, dtype="datetime64[ns]")), None
    if vt.ndim == 1:
        return np.asarray(vt.values, dtype="datetime64[ns]"), str(vt.dims[0])
    raise WeatherError(
        f"{path}: valid times form a {vt.ndim}-D array over {tuple(map(str, vt.dims))} "
        "(several analysis times AND several forecast steps); select one analysis time or one step first"
    )


# --------------------------------------------------------------------------------------
# International Standard Atmosphere
# --------------------------------------------------------------------------------------

_G0 = 9.80665  # m/s², standard gravity
_R_AIR = 287.05287  # J/(kg K), specific gas constant of dry air
_P0_HPA = 1013.25  # sea-level pressure
_T0_K = 288.15  # sea-level temperature
_LAPSE_TROPO = -0.0065  # K/m, troposphere (temperature falls with height)
_H_TROPOPAUSE = 11_000.0  # m
_T_TROPOPAUSE = _T0_K + _LAPSE_TROPO * _H_TROPOPAUSE  # 216.65 K
_H_STRATO = 20_000.0  # m, top of the isothermal layer
_LAPSE_STRATO = 0.001  # K/m, 20..32 km (temperature rises again)
_H_TOP = 32_000.0  # m, top of the layers we model

_P_TROPOPAUSE = _P0_HPA * (_T_TROPOPAUSE / _T0_K) ** (-_G0 / (_R_AIR * _LAPSE_TROPO))  # ≈ 226.32 hPa
_P_STRATO = _P_TROPOPAUSE * np.exp(-_G0 * (_H_STRATO - _H_TROPOPAUSE) / (_R_AIR * _T_TROPOPAUSE))  # ≈ 54.75 hPa


def isa_pressure_hpa(alt_m: np.ndarray) -> np.ndarray:
    """Pressure (hPa) at geopotential altitude ``alt_m`` (m) in the ISA.

    Layers: troposphere (0..11 km, -6.5 K/km), isothermal tropopause layer
    (11..20 km, 216.65 K); for completeness the 20..32 km layer (+1 K/km) is also
    modelled, which covers the 10 hPa top level of GFS.  Altitudes below 0 m use
    the troposphere formula (valid down to about -5 km).  NaN stays NaN.

    This is the standard way to map a *pressure* altitude (what a barometric
    altimeter set to 1013.25 hPa shows, i.e. ADS-B barometric altitude) back to the
    pressure level the aircraft is flying on.
    """
    h = np.asarray(alt_m, dtype=np.float64)
    h_tropo = np.minimum(h, _H_TROPOPAUSE)
    t_tropo = _T0_K + _LAPSE_TROPO * h_tropo
    p = _P0_HPA * (t_tropo / _T0_K) ** (-_G0 / (_R_AIR * _LAPSE_TROPO))
    # Isothermal layer: exponential decay with height.
    h_iso = np.clip(h, _H_TROPOPAUSE, _H_STRATO) - _H_TROPOPAUSE
    p = np.where(h > _H_TROPOPAUSE, _P_TROPOPAUSE * np.exp(-_G0 * h_iso / (_R_AIR * _T_TROPOPAUSE)), p)
    # Lower stratosphere: temperature rises again.
    h_up = np.clip(h, _H_STRATO, _H_TOP) - _H_STRATO
    t_up = _T_TROPOPAUSE + _LAPSE_STRATO * h_up
    p_up = _P_STRATO * (t_up / _T_TROPOPAUSE) ** (-_G0 / (_R_AIR * _LAPSE_STRATO))
    return np.where(h > _H_STRATO, p_up, p)


def share_outside_levels(weather: pl.DataFrame, alt_m: np.ndarray) -> float:
    """Share of altitudes whose ISA pressure lies above the weather's highest or below its lowest level:
    `sample_weather` gives those the nearest level's values (a 200-300 hPa file: a climb at 1 km gets 300 hPa air)."""
    p = isa_pressure_hpa(alt_m)
    lo, hi = weather["level_hpa"].min(), weather["level_hpa"].max()
    return float(np.mean((p < lo) | (p > hi))) if p.size else 0.0


def isa_altitude_m(pressure_hpa: np.ndarray) -> np.ndarray:
    """Inverse of ``isa_pressure_hpa``: ISA altitude (m) of a pressure (hPa), up to 32 km.

    Handy to label pressure levels with flight levels (250 hPa ≈ 10,363 m ≈ FL340).
    """
    p = np.asarray(pressure_hpa, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        h_tropo = (_T0_K / _LAPSE_TROPO) * ((p / _P0_HPA) ** (-_R_AIR * _LAPSE_TROPO / _G0) - 1.0)
        h_iso = _H_TROPOPAUSE - (_R_AIR * _T_TROPOPAUSE / _G0) * np.log(p / _P_TROPOPAUSE)
        h_up = _H_STRATO + (_T_TROPOPAUSE / _LAPSE_STRATO) * (
            (p / _P_STRATO) ** (-_R_AIR * _LAPSE_STRATO / _G0) - 1.0
        )
    return np.where(p >= _P_TROPOPAUSE, h_tropo, np.where(p >= _P_STRATO, h_iso, h_up))


# --------------------------------------------------------------------------------------
# Time alignment
# --------------------------------------------------------------------------------------

ALIGNMENTS = ("exact", "time_of_day")

_US_PER_DAY = 86_400_000_000
_NAT = np.iinfo(np.int64).min  # how numpy stores NaT in an int64 view


def weather_time_range(weather: pl.DataFrame) -> tuple[dt.datetime, dt.datetime]:
    """First and last valid time of a weather table, as timezone-aware UTC datetimes."""
    if "time" not in weather.columns or weather.height == 0:
        raise WeatherError("weather table is empty or has no 'time' column")
    start, end = weather["time"].min(), weather["time"].max()
    if start is None or end is None:
        raise WeatherError("weather table has no valid time")
    return _as_utc_datetime(start), _as_utc_datetime(end)


def _as_utc_datetime(value: Any) -> dt.datetime:
    if isinstance(value, dt.datetime):
        return value.replace(tzinfo=dt.UTC) if value.tzinfo is None else value.astimezone(dt.UTC)
    raise WeatherError(f"expected a datetime, got {value!r}")


def _to_epoch_us(ts: Any) -> np.ndarray:
    """UTC timestamps (numpy datetime64 array or polars Datetime Series) -> int64 µs since 1970.

    Naive timestamps are taken as UTC; NaT/null become the NaT sentinel.
    """
    if isinstance(ts, pl.Series):
        if not isinstance(ts.dtype, pl.Datetime):
            raise WeatherError(f"ts must be a Datetime series, got dtype {ts.dtype}")
        if ts.dtype.time_zone is not None:
            ts = ts.dt.convert_time_zone("UTC").dt.replace_time_zone(None)
        return ts.dt.cast_time_unit("us").to_numpy().astype("datetime64[us]").view(np.int64)
    arr = np.asarray(ts)
    if not np.issubdtype(arr.dtype, np.datetime64):
        raise WeatherError(f"ts must be numpy datetime64 values or a polars Datetime series, got dtype {arr.dtype}")
    return arr.astype("datetime64[us]").view(np.int64).ravel()


def _fmt_us(us: int) -> str:
    return str(np.datetime64(int(us), "us").astype("datetime64[s]")).replace("T", " ")


def align_times(point_us: np.ndarray, weather_us: np.ndarray, alignment: str) -> np.ndarray:
    """Map point times (int64 µs UTC) onto the weather's time axis (int64 µs UTC).

    - ``"exact"``: keep the real timestamps.  Every point must lie inside the
      weather's time range, otherwise WeatherError names both ranges.
    - ``"time_of_day"``: keep only each point's UTC time of day, put it on the
      first (UTC) day of the weather data, then clamp it into the weather's time
      range.  Example: with weather 2019-01-05 01:00..10:00, a point at
      2022-03-01 06:30 is sampled at 2019-01-05 06:30, and one at 2022-03-01 18:00
      at 2019-01-05 10:00 (clamped).  With single-time weather (one GFS forecast)
      every point uses that one time.  This is a *climatological stand-in*, useful
      when the available weather is not from the flights' dates; it is not the
      weather those flights met.

    NaT points stay NaT (and give NaN when sampled).
    """
    if alignment not in ALIGNMENTS:
        raise WeatherError(f"alignment must be one of {ALIGNMENTS}, got {alignment!r}")
    start, end = int(weather_us.min()), int(weather_us.max())
    valid = point_us != _NAT
    if alignment == "exact":
        outside = valid & ((point_us < start) | (point_us > end))
        if outside.any():
            pts = point_us[valid]
            raise WeatherError(
                f"{int(outside.sum())} of {point_us.size} points lie outside the weather time range: "
                f"points {_fmt_us(pts.min())} .. {_fmt_us(pts.max())} UTC, "
                f"weather {_fmt_us(start)} .. {_fmt_us(end)} UTC; "
                "if the weather is deliberately from another date, set weather_alignment (tracks_20s) to 'time_of_day'"
            )
        return point_us.copy()
    first_day = start - start % _US_PER_DAY  # midnight UTC of the weather's first day
    aligned = first_day + np.mod(point_us, _US_PER_DAY)
    aligned = np.clip(aligned, start, end)
    return np.where(valid, aligned, _NAT)


# --------------------------------------------------------------------------------------
# Sampling
# --------------------------------------------------------------------------------------


def _weather_grid(weather: pl.DataFrame) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rebuild the regular grid behind a weather table.

    Returns (time µs, level hPa, lat, lon, values) with values shaped
    (time, level, lat, lon, 3) in the order of _VALUE_COLUMNS.
    """
    missing = [c for c in (*_KEY_COLUMNS, *_VALUE_COLUMNS) if c not in weather.columns]
    if missing:
        raise WeatherError(f"weather table lacks columns {missing}; pass the table read_weather returns")
    if weather.height == 0:
        raise WeatherError("weather table is empty")
    if not isinstance(weather.schema["time"], pl.Datetime):
        raise WeatherError(f"weather column 'time' must be a Datetime, got {weather.schema['time']}")
    w = weather.select(
        pl.col("time").dt.epoch("us"),  # an absolute instant, whatever the time zone
        *[pl.col(c).cast(pl.Float64) for c in ("level_hpa", "lat", "lon", *_VALUE_COLUMNS)],
    )
    # read_weather's output is already sorted; checking is as cheap as sorting, so just sort.
    w = w.sort(list(_KEY_COLUMNS))
    axes = [np.unique(w[c].to_numpy()) for c in _KEY_COLUMNS]
    shape = tuple(a.size for a in axes)
    if int(np.prod(shape)) != w.height:
        raise WeatherError(
            f"weather table is not a complete time x level x lat x lon grid: {w.height} rows for axes of sizes "
            f"{shape} (= {int(np.prod(shape))}); filter whole times/levels/lat/lon only"
        )
    # Same row count can still hide a duplicate + a hole: check each key column's pattern.
    for k, (column, axis) in enumerate(zip(_KEY_COLUMNS, axes)):
        pattern = np.broadcast_to(axis.reshape([-1 if i == k else 1 for i in range(4)]), shape).reshape(-1)
        if not np.array_equal(w[column].to_numpy(), pattern):
            raise WeatherError(f"weather table is not a complete grid: column {column!r} does not tile regularly")
    if not (axes[1] > 0).all():
        raise WeatherError(f"weather pressure levels must be positive hPa, got {axes[1]}")
    values = np.stack([w[c].to_numpy().reshape(shape) for c in _VALUE_COLUMNS], axis=-1)
    return axes[0], axes[1], axes[2], axes[3], values


def _axis_weights(axis: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Left-neighbour index and linear weight of the right neighbour, clamped at the ends.

    `axis` must be increasing.  For a length-1 axis the index is 0 and the weight 0.
    """
    if axis.size == 1:
        return np.zeros(q.shape, dtype=np.intp), np.zeros(q.shape, dtype=np.float64)
    steps = np.diff(axis)
    if np.allclose(steps, steps[0], rtol=1e-9, atol=0):
        # Evenly spaced (lat, lon, hourly times): the cell index is plain arithmetic,
        # several times faster than a binary search over the axis.
        pos = (q - axis[0]) / steps[0]
        i0 = np.clip(np.floor(np.nan_to_num(pos)), 0, axis.size - 2).astype(np.intp)
    else:
        i0 = np.clip(np.searchsorted(axis, q, side="right") - 1, 0, axis.size - 2)
    left = axis[i0]
    w = (q - left) / (axis[i0 + 1] - left)
    np.clip(w, 0.0, 1.0, out=w)  # clip = clamp to the end nodes
    return i0, np.nan_to_num(w, nan=0.0, copy=False)


def _unwrap_longitudes(lon: np.ndarray) -> tuple[np.ndarray, np.ndarray, bool]:
    """Make the longitude axis continuous and say whether it wraps around the globe.

    Returns (unwrapped increasing axis, column order to apply to the grid, periodic).
    The grid is cut at its largest gap, so a box across the antimeridian
    (170..180, -180..-170) becomes 170..190, and a global grid is periodic.
    """
    n = lon.size
    if n == 1:
        return lon.copy(), np.arange(1), False
    gaps = np.diff(np.append(lon, lon[0] + 360.0))  # last entry: the gap across the wrap
    cut = int(np.argmax(gaps))  # the largest gap is where the grid "ends"
    order = np.roll(np.arange(n), -(cut + 1))
    unwrapped = lon[order].copy()
    unwrapped[unwrapped < unwrapped[0]] += 360.0
    # Periodic when the gap across the end is no wider than a normal grid step.
    interior = np.diff(unwrapped)
    periodic = bool(gaps[cut] <= interior.max() * (1 + 1e-6) + 1e-9)
    return unwrapped, order, periodic


def sample_weather(
    weather: pl.DataFrame,
    ts: Any,
    lat: np.ndarray,
    lon: np.ndarray,
    alt_m: np.ndarray,
    alignment: str = "exact",
) -> dict[str, np.ndarray]:
    """Interpolate temperature and wind at many points at once.

    Arguments: ``weather`` as returned by ``read_weather``; ``ts`` UTC timestamps
    (numpy datetime64 array, naive = UTC, or a polars Datetime Series); ``lat``,
    ``lon`` in degrees (any longitude convention: -180..180 or 0..360); ``alt_m``
    ISA pressure altitude in metres (ADS-B barometric altitude).  All of length N.

    Returns ``{"temperature_k", "wind_u_mps", "wind_v_mps"}``, each float64 of length N.

    How each point is interpolated (4-D multilinear, vectorised, no loop over points):

    - time: linear between the two bracketing weather times, after ``alignment``:

      * ``"exact"`` (default): each point uses its real timestamp; if any point
        lies outside the weather's time range, WeatherError names both ranges.
      * ``"time_of_day"``: each point keeps only its UTC time of day, placed on
        the first (UTC) day of the weather and clamped into the weather's time
        range (e.g. weather 2019-01-05 01:00..10:00: a point at 2022-03-01 06:30
        uses 2019-01-05 06:30, one at 23:00 uses 10:00).  A stand-in for when the
        weather is not from the flights' dates; see ``align_times``.

    - vertical: the altitude becomes a pressure with ``isa_pressure_hpa`` and is
      interpolated linearly in log-pressure between the two bracketing levels
      (log p is nearly proportional to height).  Points above the highest level or
      below the lowest level are CLAMPED to that level: they get its values;
    - horizontal: bilinear in latitude/longitude; longitudes wrap around on a
      global grid.  Points outside a regional grid (or NaN inputs) give NaN.

    The grid is rebuilt once per call and each of the <= 16 surrounding nodes is
    one vectorised gather, so 1,000,000 points take about 0.6 s on one core.
    """
    t_axis_us, levels, lat_axis, lon_axis, values = _weather_grid(weather)

    # --- inputs: one flat float array each, same length ---------------------------------
    point_us = _to_epoch_us(ts)
    lat_q = np.asarray(lat, dtype=np.float64).ravel()
    lon_q = np.asarray(lon, dtype=np.float64).ravel()
    alt_q = np.asarray(alt_m, dtype=np.float64).ravel()
    sizes = {"ts": point_us.size, "lat": lat_q.size, "lon": lon_q.size, "alt_m": alt_q.size}
    if len(set(sizes.values())) != 1:
        raise WeatherError(f"ts, lat, lon and alt_m must have the same length, got {sizes}")
    n = lat_q.size
    if n == 0:
        return {c: np.empty(0, dtype=np.float64) for c in _VALUE_COLUMNS}

    # --- time: align, then work in seconds since the first weather time (float-safe) ----
    aligned_us = align_times(point_us, t_axis_us, alignment)
    nat = aligned_us == _NAT
    t_axis = (t_axis_us - t_axis_us[0]) / 1e6
    t_q = (np.where(nat, t_axis_us[0], aligned_us) - t_axis_us[0]) / 1e6

    # --- vertical: altitude -> pressure -> log-pressure ---------------------------------
    # Levels are sorted by increasing hPa, so log-pressure is increasing too.
    z_axis = np.log(levels)
    z_q = np.log(isa_pressure_hpa(alt_q))

    # --- horizontal: continuous longitudes, periodic grid gets its first column repeated --
    lon_axis, lon_order, periodic = _unwrap_longitudes(lon_axis)
    values = values[:, :, :, lon_order]
    if periodic:
        lon_axis = np.append(lon_axis, lon_axis[0] + 360.0)
        values = np.concatenate([values, values[:, :, :, :1]], axis=3)
    # Put each query longitude in [first grid lon, first grid lon + 360).
    lon_q = lon_axis[0] + np.mod(lon_q - lon_axis[0], 360.0)
    outside = ~((lat_q >= lat_axis[0]) & (lat_q <= lat_axis[-1]))  # also True for NaN
    outside |= np.isnan(lon_q) | nat | np.isnan(z_q)
    if not periodic:
        outside |= lon_q > lon_axis[-1]

    # --- weights along each axis, then sum over the 2^4 surrounding grid nodes ----------
    per_axis = [
        _axis_weights(t_axis, t_q),
        _axis_weights(z_axis, z_q),
        _axis_weights(lat_axis, lat_q),
        _axis_weights(lon_axis, lon_q),
    ]
    shape = values.shape[:4]
    strides = [int(np.prod(shape[k + 1 :])) for k in range(4)]
    base = sum(i0 * stride for (i0, _), stride in zip(per_axis, strides))
    # Each axis contributes (1 - w) to its lower node and w to its upper node; a
    # length-1 axis (e.g. a single forecast time) has only the lower node.
    options = [
        [(0, 1.0 - w), (1, w)] if shape[k] > 1 else [(0, 1.0)]
        for k, (_, w) in enumerate(per_axis)
    ]
    # Multiply weights pairwise (time x level, lat x lon) to save multiplications.
    time_level = [(ct * strides[0] + cl * strides[1], wt * wl) for ct, wt in options[0] for cl, wl in options[1]]
    lat_lon = [(cy * strides[2] + cx * strides[3], wy * wx) for cy, wy in options[2] for cx, wx in options[3]]
    fields = [np.ascontiguousarray(values[..., k]).reshape(-1) for k in range(values.shape[-1])]
    results = [np.zeros(n, dtype=np.float64) for _ in fields]
    gathered = np.empty(n, dtype=np.float64)
    index = np.empty(n, dtype=np.intp)
    for off_tl, w_tl in time_level:  # at most 4 x 4 = 16 corners; never a loop over points
        for off_yx, w_yx in lat_lon:
            weight = w_tl * w_yx
            np.add(base, off_tl + off_yx, out=index)
            for field, result in zip(fields, results):
                np.take(field, index, out=gathered)
                gathered *= weight
                result += gathered
    for result in results:
        result[outside] = np.nan
    return dict(zip(_VALUE_COLUMNS, results))
