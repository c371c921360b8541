"""Rebuild the compact weather copies shipped in data/weather/ from the originals.

The originals (a 3.8 MB GFS GRIB2 file and an 8.9 MB ERA5 NetCDF4 file) are too
big and too broad to ship in the repository, so the tests use small *subsets*.
The subsets stay real data: GRIB messages are copied byte for byte, and the
ERA5 values keep their original int16 packing (scale_factor / add_offset), so
every value in the copy is bit-identical to the same value in the original.

Usage (from the repository root)::

    python data/weather/make_compact.py \
        --gfs  /path/to/gfs_2011_global_2p5deg_26levels.grib2 \
        --era5 /path/to/era5_2019-01-05_global_2deg_200-300hPa.nc \
        --out  data/weather

Either input may be left out to rebuild only the other copy.
Reading and writing NetCDF4 needs h5netcdf *and* h5py.
"""

from __future__ import annotations

import argparse
from pathlib import Path

GFS_OUT_NAME = "gfs_2011_isobaric_t_u_v.grib2"
ERA5_OUT_NAME = "era5_2019-01-05_europe_200-300hPa.nc"

# What the GRIB copy keeps: temperature and wind on pressure levels.
GFS_KEEP_LEVEL_TYPE = "isobaricInhPa"
GFS_KEEP_SHORT_NAMES = {"t", "u", "v"}

# What the ERA5 copy keeps: a box over Europe and the three fields we use.
ERA5_LAT = (40.0, 70.0)
ERA5_LON = (0.0, 50.0)
# The pycontrails copy of ERA5 uses CF standard names; plain ERA5 downloads use t/u/v.
ERA5_KEEP = {
    "t": ("t", "air_temperature"),
    "u": ("u", "eastward_wind"),
    "v": ("v", "northward_wind"),
}


def compact_gfs(src: Path, dst: Path) -> int:
    """Copy the isobaric t/u/v GRIB messages of `src` unchanged into `dst`.

    NCEP packs u and v into ONE multi-field GRIB2 message.  We therefore keep
    multi-field support OFF, so that each handle is one physical message: the
    combined u+v message reports shortName "u" (its first field) and is copied
    whole, which keeps v as well.  Returns the number of messages written.
    """
    import eccodes

    eccodes.codes_grib_multi_support_off()
    kept = 0
    with open(src, "rb") as fin, open(dst, "wb") as fout:
        while True:
            handle = eccodes.codes_grib_new_from_file(fin)
            if handle is None:
                break
            try:
                level_type = eccodes.codes_get(handle, "typeOfLevel")
                short_name = eccodes.codes_get(handle, "shortName")
                if level_type == GFS_KEEP_LEVEL_TYPE and short_name in GFS_KEEP_SHORT_NAMES:
                    eccodes.codes_write(handle, fout)  # raw bytes of the message
                    kept += 1
            finally:
                eccodes.codes_release(handle)
    return kept


def compact_era5(src: Path, dst: Path) -> None:
    """Crop ERA5 to Europe, keep temperature and wind, write zlib-compressed NetCDF4."""
    import xarray as xr

    with xr.open_dataset(src, engine="h5netcdf") as ds:
        keep = []
        for field, candidates in ERA5_KEEP.items():
            found = [name for name in candidates if name in ds.data_vars]
            if not found:
                raise SystemExit(f"{src}: no variable for {field!r} (tried {candidates})")
            keep.append(found[0])
        lat_name = "latitude" if "latitude" in ds.coords else "lat"
        lon_name = "longitude" if "longitude" in ds.coords else "lon"
        sub = ds[keep]
        lat = sub[lat_name]
        lon = sub[lon_name]
        # Boolean masks work whatever the axis order (ERA5 latitudes often run north -> south).
        sub = sub.isel(
            {
                lat_name: ((lat >= ERA5_LAT[0]) & (lat <= ERA5_LAT[1])).values,
                lon_name: ((lon >= ERA5_LON[0]) & (lon <= ERA5_LON[1])).values,
            }
        ).load()
        sub.attrs["history"] = (
            sub.attrs.get("history", "")
            + f"\nsubset by trafficlearn data/weather/make_compact.py: variables {keep}, "
            f"latitude {ERA5_LAT[0]}..{ERA5_LAT[1]}, longitude {ERA5_LON[0]}..{ERA5_LON[1]}"
        ).strip()
        encoding = {}
        for name in sub.variables:
            enc = {
                key: value
                for key, value in sub[name].encoding.items()
                # Keep the original packing (so values are bit-identical); drop layout keys
                # that described the old file and would not fit the cropped arrays.
                if key in ("dtype", "scale_factor", "add_offset", "_FillValue", "units", "calendar")
            }
            if name in sub.data_vars:
                enc.update(zlib=True, complevel=9, shuffle=True)
            encoding[name] = enc
        sub.to_netcdf(dst, engine="h5netcdf", format="NETCDF4", encoding=encoding)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gfs", type=Path, help="original GFS GRIB2 file")
    parser.add_argument("--era5", type=Path, help="original ERA5 NetCDF file")
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parent)
    args = parser.parse_args(argv)
    if args.gfs is None and args.era5 is None:
        parser.error("give --gfs and/or --era5")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.gfs is not None:
        dst = args.out / GFS_OUT_NAME
        n = compact_gfs(args.gfs, dst)
        print(f"{dst}: {n} GRIB messages, {dst.stat().st_size:,} bytes")
    if args.era5 is not None:
        dst = args.out / ERA5_OUT_NAME
        compact_era5(args.era5, dst)
        print(f"{dst}: {dst.stat().st_size:,} bytes")


if __name__ == "__main__":
    main()
