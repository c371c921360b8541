"""Actual vs predicted trajectories of every method: a rerun recording (3D + map, one timeline) and an MCAP
file of Foxglove `foxglove.LocationFix` messages (JSON encoding) for Foxglove Studio's map panel.

Both take the long table of points (source = "actual" or a method name, flight_id, ts, lat, lon, alt_m)
built by `points_for_recording`. rerun entity paths: `flights/<flight_id>/<source>`; MCAP topics:
`/trajectory/<source>` (spaces as _, e.g. `/trajectory/bc_single`) with frame_id = flight_id.
"""

import json
import uuid
from pathlib import Path

import numpy as np
import polars as pl
import rerun as rr
import rerun.blueprint as rrb

from models.aviation.plots import MODE_COLORS
from models.aviation.recording import local_frame
from warehouse.storage import replace_atomically

APPLICATION_ID = "trafficlearn_trajectory_predictions"
ACTUAL_COLOR = np.array([220, 30, 30], dtype=np.uint8)
LOCATION_FIX_SCHEMA = {
    "title": "foxglove.LocationFix",
    "type": "object",
    "properties": {
        "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}},
        "frame_id": {"type": "string"},
        "latitude": {"type": "number"},
        "longitude": {"type": "number"},
        "altitude": {"type": "number"},
        "position_covariance": {"type": "array", "items": {"type": "number"}},
        "position_covariance_type": {"type": "integer"},
        "color": {"type": "object"},
    },
}


def points_for_recording(tracks: pl.DataFrame, predictions: pl.DataFrame, seed: int = 0) -> pl.DataFrame:
    """Actual test tracks + every method's prediction of one seed, as (source, flight_id, ts, lat, lon, alt_m)."""
    pred = predictions.filter(pl.col("seed") == seed).with_columns(
        pl.concat_str("method", pl.lit(" "), "scheme").alias("source"))
    flights = pred["flight_id"].unique()
    actual = tracks.filter(pl.col("flight_id").is_in(flights.implode())).with_columns(pl.lit("actual").alias("source"))
    cols = ["source", "flight_id", "ts", "lat", "lon", "alt_m"]
    return pl.concat([actual.select(cols), pred.select(cols)]).sort("flight_id", "source", "ts")


def _color(source: str, sources: list[str]) -> np.ndarray:
    if source == "actual":
        return ACTUAL_COLOR
    h = MODE_COLORS[sources.index(source) % len(MODE_COLORS)].lstrip("#")
    return np.array([int(h[i: i + 2], 16) for i in (0, 2, 4)], dtype=np.uint8)


def _atomic(path: Path, suffix: str, write) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    return replace_atomically(path, write, suffix)


def write_prediction_recording(points: pl.DataFrame, path: Path, vertical_exaggeration: float = 10.0) -> Path:
    """rerun .rrd: per flight and source a static 3D line + map line, and the moving aircraft on the `time` timeline."""
    xyz = local_frame(points, vertical_exaggeration)
    latlon = points.select("lat", "lon").to_numpy()
    ts = points["ts"].dt.replace_time_zone(None).to_numpy().astype("datetime64[ns]")
    runs = points.group_by("flight_id", "source", maintain_order=True).agg(n=pl.len())
    bounds = np.concatenate([[0], np.cumsum(runs["n"].to_numpy().astype(np.int64))])
    sources = sorted(points["source"].unique().to_list())

    def write(tmp: str) -> None:
        rec = rr.RecordingStream(APPLICATION_ID, recording_id=uuid.uuid4())
        rec.save(tmp, default_blueprint=rrb.Blueprint(rrb.Horizontal(
            rrb.Spatial3DView(origin="flights", name=f"3D: east/north km, altitude km x{vertical_exaggeration:g}"),
            rrb.MapView(origin="flights", name="map")), collapse_panels=False))
        rec.log("flights", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("description", rr.TextDocument("Actual (red) and predicted trajectories of every method on the test flights.\n"
                                               f"Sources: {', '.join(sources)}"), static=True)
        for (fid, source, _), a, b in zip(runs.iter_rows(), bounds[:-1], bounds[1:]):
            ent = "/".join(rr.escape_entity_path_part(p) for p in ("flights", fid, source))
            color = _color(source, sources)
            rec.log(ent, rr.LineStrips3D([xyz[a:b]], colors=[color]), rr.GeoLineStrings(lat_lon=[latlon[a:b]], colors=[color]), static=True)
            n = int(b - a)
            rec.send_columns(f"{ent}/aircraft", indexes=[rr.TimeColumn("time", timestamp=ts[a:b])], columns=[
                *rr.Points3D.columns(positions=xyz[a:b], colors=np.broadcast_to(color, (n, 3))),
                *rr.GeoPoints.columns(positions=latlon[a:b], colors=np.broadcast_to(color, (n, 3)))])
        rec.flush()
        rec.disconnect()

    return _atomic(Path(path), ".rrd", write)


def write_location_fix_mcap(points: pl.DataFrame, path: Path) -> Path:
    """MCAP with one `foxglove.LocationFix` JSON message per point, topic per source, log time = the point's time."""
    from mcap.writer import Writer

    sources = sorted(points["source"].unique().to_list())
    t_ns = points["ts"].dt.epoch("ns").to_numpy()
    order = np.argsort(t_ns, kind="stable")  # MCAP readers expect messages roughly in log-time order
    src, fid = points["source"].to_numpy(), points["flight_id"].to_numpy()
    lat, lon, alt = (points[c].to_numpy() for c in ("lat", "lon", "alt_m"))

    def write(tmp: str) -> None:
        with open(tmp, "wb") as f:
            w = Writer(f)
            w.start(profile="", library="trafficlearn")
            schema = w.register_schema("foxglove.LocationFix", "jsonschema", json.dumps(LOCATION_FIX_SCHEMA).encode())
            chan = {s: w.register_channel(f"/trajectory/{s.replace(' ', '_')}", "json", schema) for s in sources}
            colors = {s: _color(s, sources) / 255.0 for s in sources}
            for i in order:
                t = int(t_ns[i])
                c = colors[src[i]]
                msg = {"timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000}, "frame_id": str(fid[i]),
                       "latitude": float(lat[i]), "longitude": float(lon[i]), "altitude": float(alt[i]),
                       "position_covariance": [0.0] * 9, "position_covariance_type": 0,
                       "color": {"r": float(c[0]), "g": float(c[1]), "b": float(c[2]), "a": 1.0}}
                w.add_message(chan[src[i]], log_time=t, data=json.dumps(msg).encode(), publish_time=t)
            w.finish()

    return _atomic(Path(path), ".mcap", write)
