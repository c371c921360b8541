"""Predict flights to their destination with a trained model.

    python -m models.trajectory.predict --model var/models/trajectory/triple_gail_bce_gp_MMIL_seed0.pt \
        --flights first_states.parquet --out predicted.parquet

--flights: Parquet (or CSV) with columns flight_id, ts (UTC), lon (deg), lat (deg), alt_m (m), route (e.g.
UUEE-UMKK); the earliest row of each flight is its first state (more rows are allowed, e.g. whole tracks).
--out: Parquet with flight_id, method, scheme, phase, step, ts, lat, lon, alt_m, mode.
Bad model files and bad inputs stop with one line naming the problem (exit code 2).
"""

import argparse
import sys
from pathlib import Path

import numpy as np
import polars as pl

from models.trajectory.model import TrajectoryModel, TrajectoryModelError

REQUIRED = {"flight_id": pl.String, "ts": None, "lon": pl.Float64, "lat": pl.Float64, "alt_m": pl.Float64, "route": pl.String}


class PredictionInputError(ValueError):
    """The flights file cannot be used (message names the file and column)."""


def read_first_states(path: str | Path) -> pl.DataFrame:
    path = Path(path)
    if not path.is_file():
        raise PredictionInputError(f"flights file {path}: not found")
    try:
        df = pl.read_parquet(path) if path.suffix != ".csv" else pl.read_csv(path, try_parse_dates=True)
    except Exception as exc:  # noqa: BLE001 — any reader failure means "not a readable table"
        raise PredictionInputError(f"flights file {path}: not a readable Parquet/CSV file ({type(exc).__name__})") from None
    missing = [c for c in REQUIRED if c not in df.columns]
    if missing:
        raise PredictionInputError(f"flights file {path}: missing column(s) {', '.join(missing)} (need {', '.join(REQUIRED)})")
    if df.is_empty():  # before the type checks: a header-only CSV has string columns
        raise PredictionInputError(f"flights file {path}: no rows")
    if df.schema["ts"] == pl.String:  # ISO strings, as a CSV's are parsed
        parsed = df["ts"].str.to_datetime(time_zone="UTC", strict=False)
        if parsed.null_count() == df["ts"].null_count():
            df = df.with_columns(ts=parsed)
    if not df.schema["ts"].is_temporal():
        raise PredictionInputError(f"flights file {path}: column ts must be a UTC timestamp, got {df.schema['ts']}")
    try:
        df = df.with_columns(pl.col(c).cast(pl.Float64, strict=True) for c in ("lon", "lat", "alt_m"))
    except Exception:  # noqa: BLE001
        raise PredictionInputError(f"flights file {path}: lon, lat, alt_m must be numbers") from None
    first = df.sort("flight_id", "ts").group_by("flight_id", maintain_order=True).first()
    if first.is_empty():
        raise PredictionInputError(f"flights file {path}: no rows")
    # the first state is the whole input: a missing value would roll out NaN, -5 km would "fly" underground
    gaps = first.filter(pl.any_horizontal(pl.col(c).is_null() | pl.col(c).is_nan() for c in ("lon", "lat", "alt_m")))
    if not gaps.is_empty():
        raise PredictionInputError(f"flights file {path}: missing or NaN lon/lat/alt_m in the first state of flight {gaps['flight_id'][0]}")
    bad = first.filter(~pl.col("lat").is_between(-90, 90) | ~pl.col("lon").is_between(-180, 180))
    if not bad.is_empty():
        raise PredictionInputError(f"flights file {path}: lat/lon out of range (degrees expected) for flight {bad['flight_id'][0]}")
    if (first["alt_m"] > 20_000).any():
        raise PredictionInputError(f"flights file {path}: column alt_m above 20,000 — feet instead of metres?")
    if (first["alt_m"] < -500).any():
        raise PredictionInputError(f"flights file {path}: column alt_m below -500 m")
    return first


def predict_flights(model: TrajectoryModel, first: pl.DataFrame) -> pl.DataFrame:
    """Whole-flight prediction for every flight of `first` (one row per flight: its first state)."""
    lon0, lat0, lon1, lat1 = model.bbox
    m = model.env.cfg.bbox_margin_deg  # beyond it the environment ends the roll-out at its first step
    away = first.filter(~pl.col("lon").is_between(lon0 - m, lon1 + m) | ~pl.col("lat").is_between(lat0 - m, lat1 + m))
    if not away.is_empty():
        f = away.row(0, named=True)
        raise PredictionInputError(f"flight {f['flight_id']}: first state lat {f['lat']:.2f}, lon {f['lon']:.2f} lies outside the area the model "
                                   f"flies in (lat {lat0:.1f}..{lat1:.1f}, lon {lon0:.1f}..{lon1:.1f}): lat and lon swapped?")
    start = first.select("lon", "lat", "alt_m").to_numpy()
    start_s = first["ts"].dt.epoch("us").to_numpy() / 1e6
    out = model.predict(start, first["route"].to_list(), start_s)
    dt, rows = model.config["dt_s"], []
    step0 = np.zeros(len(start), dtype=np.int64)
    for pm in model.phases:
        pred, _ = out[pm.phase]
        for i, pts in enumerate(pred.positions):
            skip = 0 if step0[i] == 0 else 1  # a phase starts where the previous ended: don't repeat that point
            steps = step0[i] + np.arange(skip, len(pts))
            rows.append(pl.DataFrame({
                "flight_id": first["flight_id"][i], "method": model.config["method"], "scheme": model.config["scheme"], "phase": pm.phase,
                "step": steps, "ts_s": start_s[i] + steps * dt, "lat": pts[skip:, 1], "lon": pts[skip:, 0], "alt_m": pts[skip:, 2],
                "mode": pm.mode_label(pred.modes[i])}))
            step0[i] += len(pts) - 1
    df = pl.concat(rows)
    ts = pl.from_epoch((pl.col("ts_s") * 1e6).round().cast(pl.Int64), time_unit="us").dt.replace_time_zone("UTC")
    return df.with_columns(ts.alias("ts")).select("flight_id", "method", "scheme", "phase", "step", "ts", "lat", "lon", "alt_m", "mode").sort("flight_id", "step")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m models.trajectory.predict", description=__doc__.split("\n\n")[0])
    ap.add_argument("--model", required=True, help="model file (.pt) from the trajectory_models catalogue")
    ap.add_argument("--flights", required=True, help="Parquet/CSV with flight_id, ts, lon, lat, alt_m, route")
    ap.add_argument("--out", required=True, help="output Parquet (CSV if the name ends in .csv)")
    args = ap.parse_args(argv)
    try:
        model = TrajectoryModel.load(args.model)
        pred = predict_flights(model, read_first_states(args.flights))
    except (TrajectoryModelError, PredictionInputError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    if args.out.lower().endswith(".csv"):
        pred.write_csv(args.out)
    else:
        pred.write_parquet(args.out)
    print(f"{pred['flight_id'].n_unique()} flights, {pred.height} points -> {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
