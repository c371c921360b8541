"""A Rerun recording (.rrd) of the tracks coloured by route mode, to explore the modes interactively.

Open it with `rerun <file>.rrd` (viewer of rerun-sdk 0.41). Writing it is offline: the recording stream
is sunk into a file (`RecordingStream.save`), nothing spawns a viewer or opens a port.

Content, per flight, under `tracks/<route>/mode_<k>/<flight_id>`:
  * the whole path, static: `LineStrips3D` in a local metric frame and `GeoLineStrings` (lat/lon) for the
    map view, both in the mode's colour (the same fixed palette as the PNG figures);
  * `.../aircraft`: the position at every track time on the `time` timeline (`Points3D` + `GeoPoints`),
    so scrubbing the timeline moves every aircraft along its track.
Local frame: x = east and y = north in km from the mean position of all points (equirectangular, fine
over a few hundred km), z = altitude in km multiplied by `vertical_exaggeration` (10 by default:
11 km of cruise altitude against ~1,000 km of route would otherwise look flat).
"""

from __future__ import annotations

import uuid
from pathlib import Path

import numpy as np
import polars as pl
import rerun as rr
import rerun.blueprint as rrb

from models.aviation.plots import MODE_COLORS
from models.units import EARTH_RADIUS_KM
from warehouse.storage import replace_atomically

APPLICATION_ID = "trafficlearn_modes"


def _rgb(k: int) -> np.ndarray:
    h = MODE_COLORS[int(k) % len(MODE_COLORS)].lstrip("#")
    return np.array([int(h[i : i + 2], 16) for i in (0, 2, 4)], dtype=np.uint8)


def local_frame(pts: pl.DataFrame, vertical_exaggeration: float) -> np.ndarray:
    """(n, 3) east/north km from the mean position, altitude km x exaggeration."""
    lat = pts["lat"].to_numpy()
    lon = pts["lon"].to_numpy()
    lat0, lon0 = np.radians(lat.mean()), np.radians(lon.mean())
    east = EARTH_RADIUS_KM * (np.radians(lon) - lon0) * np.cos(lat0)
    north = EARTH_RADIUS_KM * (np.radians(lat) - lat0)
    up = pts["alt_m"].to_numpy() / 1000.0 * vertical_exaggeration
    return np.column_stack([east, north, up]).astype(np.float32)


def _blueprint(vertical_exaggeration: float) -> rrb.Blueprint:
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Spatial3DView(origin="tracks", name=f"3D: east/north km, altitude km x{vertical_exaggeration:g}"),
            rrb.MapView(origin="tracks", name="map"),
        ),
        collapse_panels=False,
    )


def write_modes_recording(
    tracks: pl.DataFrame,
    modes_df: pl.DataFrame,
    path: Path,
    phase: str = "all",
    vertical_exaggeration: float = 10.0,
) -> Path:
    """Write the .rrd of every flight that has a mode for `phase`; atomic (temp file + os.replace)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    m = modes_df.filter(pl.col("phase") == phase).select("flight_id", "route", "mode")
    pts = tracks.select("flight_id", "ts", "lat", "lon", "alt_m", "phase").drop_nulls(["ts", "lat", "lon", "alt_m"])
    if phase != "all":
        pts = pts.filter(pl.col("phase") == phase)
    pts = pts.join(m, on="flight_id", how="inner").sort("route", "flight_id", "ts")

    xyz = local_frame(pts, vertical_exaggeration) if pts.height else np.zeros((0, 3), np.float32)
    latlon = pts.select("lat", "lon").to_numpy()
    ts = pts["ts"].dt.replace_time_zone(None).to_numpy().astype("datetime64[ns]")  # UTC, naive for rerun
    runs = pts.group_by("flight_id", maintain_order=True).agg(pl.col("route", "mode").first(), n=pl.len())
    bounds = np.concatenate([[0], np.cumsum(runs["n"].to_numpy().astype(np.int64))])

    def write(tmp: str) -> None:
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
        rec.save(tmp, default_blueprint=_blueprint(vertical_exaggeration))  # sink first, then log
        rec.send_recording_name(f"trajectory modes, phase {phase}")
        rec.log("tracks", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True, strict=True)  # x east, y north, z up
        rec.log(
            "description",
            rr.TextDocument(
                f"Tracks coloured by route mode (phase: {phase}); {runs.height} flights.\n"
                f"3D frame: x east, y north [km] from the mean position; z altitude [km] x{vertical_exaggeration:g}.\n"
                "Timeline `time`: the flights' UTC timestamps."
            ),
            static=True,
            strict=True,
        )
        # one static log and one columnar send per flight (never per point)
        for (fid, route, mode, _), a, b in zip(runs.iter_rows(), bounds[:-1], bounds[1:]):
            ent = "/".join(rr.escape_entity_path_part(p) for p in ("tracks", route, f"mode_{mode}", fid))
            color = _rgb(mode)
            rec.log(
                ent,
                rr.LineStrips3D([xyz[a:b]], colors=[color], radii=rr.Radius.ui_points(1.0)),
                rr.GeoLineStrings(lat_lon=[latlon[a:b]], colors=[color], radii=rr.Radius.ui_points(1.5)),
                static=True,
                strict=True,
            )
            n = int(b - a)
            colors = np.broadcast_to(color, (n, 3))
            rec.send_columns(
                f"{ent}/aircraft",
                indexes=[rr.TimeColumn("time", timestamp=ts[a:b])],
                columns=[
                    *rr.Points3D.columns(positions=xyz[a:b], colors=colors, radii=np.full(n, -4.0, np.float32)),
                    *rr.GeoPoints.columns(positions=latlon[a:b], colors=colors, radii=np.full(n, -5.0, np.float32)),
                ],
                strict=True,
            )
        rec.flush()
        rec.disconnect()  # closes the file sink and writes the footer

    return replace_atomically(path, write, ".rrd")


def read_recording_summary(path: Path) -> dict:
    """Re-read an .rrd with the SDK: number of chunks and the entity paths it holds (for tests/checks)."""
    reader = rr.chunk.RrdReader(Path(path))
    chunks = list(reader.stream())
    return {"n_chunks": len(chunks), "entities": sorted({str(c.entity_path) for c in chunks})}
