"""Row order shared by the track transforms: grouped by flight, in time order within a flight."""

import numpy as np
import polars as pl

SAMPLE_EVERY = 64  # rows between the values `run_starts` samples from a sorted column


def in_flight_order(df: pl.DataFrame) -> pl.DataFrame:
    """`df` sorted by (flight_id, ts), flight_id flagged as sorted (for `run_starts`). The pipeline's frames arrive
    sorted; checking costs a fraction of a sort."""
    fid = df["flight_id"]
    if not fid.is_sorted():
        return df.sort("flight_id", "ts")
    # within a flight ts increases, so a row not later than the one before it must start a new flight: compare
    # the names there only, not on every row
    back = df.select(pl.arg_where(pl.col("ts").diff() <= pl.duration(microseconds=0))).to_series()
    if not (fid.gather(back) != fid.gather(back - 1)).all():
        return df.sort("flight_id", "ts")
    return df if fid.flags["SORTED_ASC"] else df.with_columns(pl.col("flight_id").set_sorted())


def runs(values: pl.Series, run_id: pl.Series | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(run id of every row, first row of every run) for the runs of equal consecutive values (e.g. a flight's rows);
    run_id: values.rle_id() where the caller has it."""
    run = (values.rle_id() if run_id is None else run_id).to_numpy()
    # run ids count up from 0 in row order: each run's first row is a binary search away, no pass over the rows
    return run, np.searchsorted(run, np.arange(run[-1] + 1 if len(run) else 0, dtype=run.dtype))


def run_ends(starts: np.ndarray, n: int) -> np.ndarray:
    """One past the last row of every run, from the first rows `starts` of the runs of n rows."""
    return np.r_[starts[1:], n][: len(starts)].astype(np.int64)


def run_starts(values: pl.Series) -> np.ndarray:
    """The first row of every run of equal consecutive values. A column flagged as sorted (flight_id after
    `in_flight_order`) is not compared row by row: its distinct values are taken from every SAMPLE_EVERY-th row,
    found by binary search, and the result checked (a run between two samples that a sample missed would end
    with another value than it starts with); a run-length pass over the rows where that fails or without the flag.
    int64 either way (one compiled signature for the kernels that take them)."""
    if values.flags["SORTED_ASC"] and values.len() and not values.null_count():
        sample = values.gather_every(SAMPLE_EVERY).unique(maintain_order=True)
        starts = values.search_sorted(sample, side="left").to_numpy().astype(np.int64)
        if (values.gather(starts) == values.gather(run_ends(starts, values.len()) - 1)).all():
            return starts
    return runs(values)[1].astype(np.int64, copy=False)
