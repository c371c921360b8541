"""Airspace: sectors (lateral grid cells x flight-level bands, or GeoJSON polygons with level limits),
hourly capacities, sector entry/exit events and hotspots (sector-hours whose entry count > capacity).

Demand is the *entry count* per sector and hour (thesis §5.3): a flight counts in the hour in which it
enters the sector. Everything is vectorised over all points of all flights.
"""

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import polars as pl
from matplotlib.path import Path as PolygonPath


class SectorFileError(ValueError):
    """A sector file that cannot be used (missing, not GeoJSON, a feature without geometry or levels). One line."""


@dataclass(frozen=True)
class GridSectorisation:
    """Lateral cells of `cell_lat_deg` x `cell_lon_deg` over a box, stacked in flight-level bands.

    Default: the Swiss sample's box (45.8-47.8 N, 5.9-10.5 E) in 1 deg x 1.15 deg cells (about
    110 km x 88 km, 2 x 4 cells) and 3 bands split at FL355 and FL375 (between the standard cruise
    levels, so level flight never sits on a boundary): 24 sectors."""

    lat_min: float = 45.8
    lat_max: float = 47.8
    lon_min: float = 5.9
    lon_max: float = 10.5
    cell_lat_deg: float = 1.0
    cell_lon_deg: float = 1.15
    fl_edges: tuple[float, ...] = (285.0, 355.0, 375.0, 480.0)

    def __post_init__(self):
        if self.lat_max <= self.lat_min or self.lon_max <= self.lon_min or self.cell_lat_deg <= 0 or self.cell_lon_deg <= 0:
            raise SectorFileError(f"grid sectorisation: empty box or non-positive cell size in {self}")
        if len(self.fl_edges) < 2 or any(b <= a for a, b in zip(self.fl_edges, self.fl_edges[1:])):
            raise SectorFileError(f"grid sectorisation: fl_edges {self.fl_edges} must be >= 2 increasing flight levels")

    @property
    def shape(self) -> tuple[int, int, int]:
        n_lat = math.ceil(round((self.lat_max - self.lat_min) / self.cell_lat_deg, 9))
        n_lon = math.ceil(round((self.lon_max - self.lon_min) / self.cell_lon_deg, 9))
        return n_lat, n_lon, len(self.fl_edges) - 1

    def sectors(self) -> pl.DataFrame:
        n_lat, n_lon, n_fl = self.shape
        r, c, b = (a.ravel() for a in np.meshgrid(np.arange(n_lat), np.arange(n_lon), np.arange(n_fl), indexing="ij"))
        lat0 = self.lat_min + r * self.cell_lat_deg
        lon0 = self.lon_min + c * self.cell_lon_deg
        fl = np.asarray(self.fl_edges)
        return pl.DataFrame({
            "sector": [f"R{i}C{j}_FL{int(fl[k])}-{int(fl[k + 1])}" for i, j, k in zip(r, c, b)],
            "lat_min_deg": lat0, "lat_max_deg": np.minimum(lat0 + self.cell_lat_deg, self.lat_max),
            "lon_min_deg": lon0, "lon_max_deg": np.minimum(lon0 + self.cell_lon_deg, self.lon_max),
            "fl_lower": fl[b], "fl_upper": fl[b + 1],
            "geometry_geojson": [None] * r.size,
            "capacity_per_h": [None] * r.size,
        }, schema_overrides={"geometry_geojson": pl.String, "capacity_per_h": pl.Int64})

    def locate(self, lat: np.ndarray, lon: np.ndarray, fl: np.ndarray) -> np.ndarray:
        """Sector index (row of `sectors()`) of every point, -1 outside the grid."""
        n_lat, n_lon, n_fl = self.shape
        i = np.floor((lat - self.lat_min) / self.cell_lat_deg).astype(np.int64)
        j = np.floor((lon - self.lon_min) / self.cell_lon_deg).astype(np.int64)
        k = np.searchsorted(np.asarray(self.fl_edges), fl, side="right") - 1
        inside = (lat >= self.lat_min) & (lat < self.lat_max) & (lon >= self.lon_min) & (lon < self.lon_max) & (k >= 0) & (k < n_fl)
        return np.where(inside, (i * n_lon + j) * n_fl + k, -1)


@dataclass(frozen=True)
class GeoJSONSectorisation:
    """Sectors from a GeoJSON FeatureCollection of Polygons; each feature's properties need `name`,
    `fl_lower`, `fl_upper` (flight levels) and may give `capacity_per_h`. Where sectors overlap, the
    first feature wins."""

    path: str

    def _features(self) -> list[dict]:
        p = Path(self.path)
        if not p.is_file():
            raise SectorFileError(f"{p}: no such sector file")
        try:
            doc = json.loads(p.read_text())
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise SectorFileError(f"{p}: not valid JSON ({e})") from None
        if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection" or not doc.get("features"):
            raise SectorFileError(f"{p}: expected a GeoJSON FeatureCollection with at least one feature")
        for n, f in enumerate(doc["features"]):
            props, geom = f.get("properties") or {}, f.get("geometry") or {}
            missing = [k for k in ("name", "fl_lower", "fl_upper") if props.get(k) is None]
            if missing:
                raise SectorFileError(f"{p}: feature {n} lacks properties {missing} (flight levels, e.g. fl_lower: 285)")
            if geom.get("type") != "Polygon" or not geom.get("coordinates") or len(geom["coordinates"][0]) < 4:
                raise SectorFileError(f"{p}: feature {n} ({props['name']}): geometry must be a Polygon ring of >= 4 [lon, lat] positions")
            lo, hi = props["fl_lower"], props["fl_upper"]
            if not all(isinstance(v, (int, float)) for v in (lo, hi)) or not 0 <= lo < hi <= 999:
                raise SectorFileError(f"{p}: feature {n} ({props['name']}): fl_lower {lo} / fl_upper {hi} must be flight levels 0-999, lower < upper")
            cap = props.get("capacity_per_h")
            if cap is not None and (not isinstance(cap, int) or cap < 1):
                raise SectorFileError(f"{p}: feature {n} ({props['name']}): capacity_per_h {cap!r} must be a positive integer (entries per hour)")
        names = [f["properties"]["name"] for f in doc["features"]]
        if len(set(names)) != len(names):
            raise SectorFileError(f"{p}: sector names are not unique")
        return doc["features"]

    def sectors(self) -> pl.DataFrame:
        rows = []
        for f in self._features():
            ring = np.asarray(f["geometry"]["coordinates"][0], dtype=float)
            props = f["properties"]
            rows.append({
                "sector": str(props["name"]),
                "lat_min_deg": ring[:, 1].min(), "lat_max_deg": ring[:, 1].max(),
                "lon_min_deg": ring[:, 0].min(), "lon_max_deg": ring[:, 0].max(),
                "fl_lower": float(props["fl_lower"]), "fl_upper": float(props["fl_upper"]),
                "geometry_geojson": json.dumps(f["geometry"]),
                "capacity_per_h": props.get("capacity_per_h"),
            })
        return pl.DataFrame(rows, schema_overrides={"capacity_per_h": pl.Int64})

    def locate(self, lat: np.ndarray, lon: np.ndarray, fl: np.ndarray) -> np.ndarray:
        out = np.full(lat.shape, -1, dtype=np.int64)
        xy = np.column_stack([lon, lat])
        for n, f in enumerate(self._features()):  # one vectorised test per sector, not per point
            ring = np.asarray(f["geometry"]["coordinates"][0], dtype=float)
            lo, hi = f["properties"]["fl_lower"], f["properties"]["fl_upper"]
            hit = (out < 0) & (fl >= lo) & (fl < hi)
            hit[hit] = PolygonPath(ring).contains_points(xy[hit])
            out[hit] = n
        return out


def sector_entries(points: pl.DataFrame, sectorisation) -> pl.DataFrame:
    """Points (flight_id, ts, lat, lon, fl) -> one row per sector visit: flight_id, sector, entry_ts, exit_ts.

    A visit starts at the first point inside a sector; it ends at the first point of the next visit
    (or the flight's last point), so consecutive visits share their boundary time."""
    pts = points.sort("flight_id", "ts")
    idx = sectorisation.locate(pts["lat"].to_numpy(), pts["lon"].to_numpy(), pts["fl"].to_numpy())
    names = sectorisation.sectors()["sector"]
    runs = (
        pts.with_columns(_s=pl.Series(idx))
        .with_columns(_run=pl.struct("flight_id", "_s").rle_id())
        .group_by("_run", maintain_order=True)
        .agg(pl.col("flight_id").first(), pl.col("_s").first(), entry_ts=pl.col("ts").first(), last_ts=pl.col("ts").last())
        .with_columns(exit_ts=pl.col("entry_ts").shift(-1).over("flight_id").fill_null(pl.col("last_ts")))
    )
    visits = runs.filter(pl.col("_s") >= 0)
    return visits.select("flight_id", sector=names.gather(visits["_s"]), entry_ts="entry_ts", exit_ts="exit_ts")
