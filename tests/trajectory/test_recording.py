"""The actual-vs-predicted replays: a rerun recording and an MCAP file of foxglove.LocationFix messages."""

import json
from datetime import datetime, timedelta, timezone

import polars as pl
from mcap.reader import make_reader

from models.aviation.recording import read_recording_summary
from models.trajectory.recording import write_location_fix_mcap, write_prediction_recording


def _points() -> pl.DataFrame:
    """Two flights, each as flown and as predicted by one method, five points at 20 s."""
    t0 = datetime(2022, 2, 25, 8, tzinfo=timezone.utc)
    rows = [
        {"source": source, "flight_id": fid, "ts": t0 + timedelta(seconds=20 * k),
         "lat": 55.0 + 0.01 * k + f, "lon": 37.0 - 0.02 * k, "alt_m": 9000.0 + 10 * k + (50 if source != "actual" else 0)}
        for f, fid in enumerate(["AFL1000_abc123_20220225T0800", "SDM6300_def456_20220225T0800"])
        for source in ("actual", "bc single")
        for k in range(5)
    ]
    return pl.DataFrame(rows).sort("flight_id", "source", "ts")


def test_prediction_recording_and_mcap(tmp_path):
    points = _points()
    rrd = write_prediction_recording(points, tmp_path / "replay" / "predictions.rrd")
    mcap = write_location_fix_mcap(points, tmp_path / "replay" / "predictions.mcap")
    assert sorted(p.name for p in (tmp_path / "replay").iterdir()) == ["predictions.mcap", "predictions.rrd"]  # no temp file left

    entities = read_recording_summary(rrd)["entities"]
    for fid in points["flight_id"].unique():
        assert any(e.startswith(f"/flights/{fid}/actual") for e in entities)
        assert any(e.startswith(f"/flights/{fid}/") and "bc" in e and e != f"/flights/{fid}/actual" for e in entities)

    with open(mcap, "rb") as f:
        messages = [(channel.topic, json.loads(message.data)) for _, channel, message in make_reader(f).iter_messages()]
    assert len(messages) == points.height
    assert {topic for topic, _ in messages} == {"/trajectory/actual", "/trajectory/bc_single"}  # spaces become _
    times = [m["timestamp"]["sec"] * 10**9 + m["timestamp"]["nsec"] for _, m in messages]
    assert times == sorted(times)  # in log-time order, as MCAP readers expect
    first = min(messages, key=lambda tm: (tm[1]["timestamp"]["sec"], tm[1]["frame_id"], tm[0]))[1]
    assert first["frame_id"] == "AFL1000_abc123_20220225T0800" and abs(first["latitude"] - 55.0) < 1e-9
