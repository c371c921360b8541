"""Row order shared by the track transforms: grouped by flight, in time order within a flight."""

import numpy as np
import polars as pl


def in_flight_order(df: pl.DataFrame) -> pl.DataFrame:
    """`df` sorted by (flight_id, ts). The pipeline's frames arrive sorted, with flight_id flagged as sorted (which
    makes its check free); checking costs a fraction of a sort."""
    fid = df["flight_id"]
    if not fid.is_sorted():
        return df.sort("flight_id", "ts")
    # within a flight ts increases, so a row not later than the one before it must start a new flight: compare
    # the names there only, not on every row
    back = df.select(pl.arg_where(pl.col("ts").diff() <= pl.duration(microseconds=0))).to_series()
    return df if (fid.gather(back) != fid.gather(back - 1)).all() else df.sort("flight_id", "ts")


def runs(values: pl.Series, run_id: pl.Series | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(run id of every row, first row of every run) for the runs of equal consecutive values (e.g. a flight's rows);
    run_id: values.rle_id() where the caller has it."""
    run = (values.rle_id() if run_id is None else run_id).to_numpy()
    # run ids count up from 0 in row order: each run's first row is a binary search away, no pass over the rows
    return run, np.searchsorted(run, np.arange(run[-1] + 1 if len(run) else 0, dtype=run.dtype))
