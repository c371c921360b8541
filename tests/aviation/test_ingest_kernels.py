"""The ingest's row-rule and flight-split kernels against the rules written out plainly as polars expressions (the
implementation they replaced), on random rows built to hit every reason, and one small case per reason code."""

import numpy as np
import polars as pl

from models.aviation import kernels
from models.aviation.ingest import IngestConfig

CFG = IngestConfig()


def _rows(n: int, seed: int) -> pl.DataFrame:
    """Rows in (aircraft, ts) order with many ties: equal times, repeated positions and position times (NaN ones
    too), missing position times, points on the ground (or unknown), out of range in every column."""
    rng = np.random.default_rng(seed)
    ac = np.sort(rng.integers(0, 5, n)).astype(np.uint32)
    ts = np.cumsum(rng.choice([0, 1, 1, 2], n)) * 1_000_000
    pick = lambda values, p=None: rng.choice(np.array(values, dtype=float), n, p=p)  # noqa: E731
    return pl.DataFrame(
        {
            "ac": ac,
            "ts": ts,
            "lat": pick([54.0, 54.0, 54.1, 90.0, -90.0, 90.5, -90.5]),
            "lon": pick([20.0, 20.0, 20.1, 180.0, -180.0, 180.5, -180.5]),
            "alt_m": pick([1000.0, -500.0, -501.0, 15500.0, 15501.0]),
            "onground": pl.Series(rng.choice([0, 0, 0, 1, 2], n)).replace_strict({0: False, 1: True, 2: None}, return_dtype=pl.Boolean),
            "groundspeed_mps": pl.Series(pick([200.0, 700.0, 700.5, np.nan]), nan_to_null=True),
            "pos_time": pl.Series(pick([1.0, 1.0, 2.0, np.nan, np.nan, np.inf]), nan_to_null=False).scatter(
                np.flatnonzero(rng.random(n) < 0.2), None
            ),
        }
    )


def _oracle(rows: pl.DataFrame) -> np.ndarray:
    """Reason code per row of the point rules: the first two stages as they were written in polars."""
    prev = lambda c: pl.when(pl.col("ac") == pl.col("ac").shift(1)).then(pl.col(c).shift(1))  # noqa: E731
    out_of_range = (
        ~pl.col("lat").is_between(-90, 90) | ~pl.col("lon").is_between(-180, 180)
        | ~pl.col("alt_m").is_between(CFG.min_alt_m, CFG.max_alt_m) | (pl.col("groundspeed_mps").fill_null(0) > 2 * CFG.max_speed_mps)
    )
    first = pl.coalesce(
        pl.when((pl.col("ts") == prev("ts")).fill_null(False)).then(kernels.DUPLICATE_ROW),
        pl.when(pl.col("onground").fill_null(False)).then(kernels.ON_GROUND),
        pl.when(out_of_range).then(kernels.OUT_OF_RANGE),
    ).fill_null(0)
    code = rows.with_row_index("i").with_columns(code=first)
    repeated = (
        pl.when(pl.col("pos_time").is_not_null()).then(pl.col("pos_time") == prev("pos_time"))
        .otherwise((pl.col("lat") == prev("lat")) & (pl.col("lon") == prev("lon"))).fill_null(False)
    )
    second = code.filter(pl.col("code") == 0).select("i", code=pl.when(repeated).then(kernels.REPEATED_POSITION).otherwise(0))
    reason = code["code"].to_numpy().astype(np.uint8)
    reason[second["i"].to_numpy()] = second["code"].to_numpy()
    return reason


def _point_rules(rows: pl.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """(reason per row, rows kept) from the kernel, its inputs made as clean makes them."""
    reason = np.zeros(rows.height, dtype=np.uint8)
    c = {s.name: s.to_numpy() for s in rows.select("ac", "ts", "lat", "lon", "alt_m").iter_columns()}
    kept = kernels.point_rules(
        np.arange(rows.height), c["ac"], c["ts"], c["lat"], c["lon"], c["alt_m"], rows["onground"].fill_null(False).to_numpy(),
        rows["groundspeed_mps"].fill_null(0.0).to_numpy(), rows["pos_time"].fill_null(0.0).to_numpy(),
        rows["pos_time"].is_not_null().to_numpy(), CFG.min_alt_m, CFG.max_alt_m, CFG.max_speed_mps, reason,
    )
    return reason, kept


def test_point_rules_equal_the_polars_rules():
    for seed in range(3):
        rows = _rows(5_000, seed)
        reason, kept = _point_rules(rows)
        want = _oracle(rows)
        codes = (0, kernels.DUPLICATE_ROW, kernels.ON_GROUND, kernels.OUT_OF_RANGE, kernels.REPEATED_POSITION)
        assert all((want == code).sum() > 20 for code in codes), "every reason must be hit"
        np.testing.assert_array_equal(reason, want)
        np.testing.assert_array_equal(kept, np.flatnonzero(want == 0))


def test_each_point_rule_on_its_own():
    """Per reason one row that only it rejects, and the order in which the rules are tried."""
    base = dict(ac=0, lat=54.0, lon=20.0, alt_m=1000.0, onground=False, groundspeed_mps=200.0)
    cases = [  # (changes of the second row, a second later with a new position time, reason of the second row)
        (dict(ts=0), kernels.DUPLICATE_ROW),
        (dict(ts=0, onground=True), kernels.DUPLICATE_ROW),  # a duplicate first, whatever else
        (dict(onground=True), kernels.ON_GROUND),
        (dict(onground=True, lat=91.0), kernels.ON_GROUND),
        (dict(lat=90.0001), kernels.OUT_OF_RANGE),
        (dict(lon=-180.0001), kernels.OUT_OF_RANGE),
        (dict(alt_m=15500.5), kernels.OUT_OF_RANGE),
        (dict(alt_m=-500.5), kernels.OUT_OF_RANGE),
        (dict(groundspeed_mps=700.5), kernels.OUT_OF_RANGE),
        (dict(lat=90.0, lon=-180.0, alt_m=15500.0, groundspeed_mps=700.0), 0),  # the limits themselves are in range
        (dict(lat=-90.0, lon=180.0, alt_m=-500.0), 0),
        (dict(pos_time=5.0), kernels.REPEATED_POSITION),  # the same position time
        (dict(), 0),
        (dict(pos_time=None), kernels.REPEATED_POSITION),  # none: the same latitude and longitude
        (dict(pos_time=None, lon=20.1), 0),
        (dict(pos_time=5.0, ac=1), 0),  # another aircraft
    ]
    for change, code in cases:
        first = {**base, "ts": 0, "pos_time": 5.0}
        rows = pl.DataFrame([first, {**first, "ts": 1_000_000, "pos_time": 6.0, **change}], schema_overrides={"ac": pl.UInt32, "pos_time": pl.Float64})
        reason, _ = _point_rules(rows)
        assert reason.tolist() == [0, code], change


def test_a_repeated_position_is_against_the_last_row_the_first_stage_kept():
    """Position times 5, 5 (on the ground), 5: the third row repeats the first (the second never reached the stage);
    a row the second stage rejects still is the one the next row is compared with."""
    rows = pl.DataFrame(
        {"ac": [0, 0, 0, 0], "ts": [0, 1, 2, 3], "lat": [54.0] * 4, "lon": [20.0] * 4, "alt_m": [1000.0] * 4,
         "onground": [False, True, False, False], "groundspeed_mps": [200.0] * 4, "pos_time": [5.0, 6.0, 5.0, 5.0]},
        schema_overrides={"ac": pl.UInt32},
    )
    reason, kept = _point_rules(rows)
    assert reason.tolist() == [0, kernels.ON_GROUND, kernels.REPEATED_POSITION, kernels.REPEATED_POSITION]
    assert kept.tolist() == [0]


def _split_oracle(ac, ts, cs) -> tuple[np.ndarray, np.ndarray]:
    """The flight split as it was written in polars and numpy: callsigns carried forward per aircraft."""
    frame = pl.DataFrame({"ac": ac, "row": np.arange(len(ac)), "cs": pl.Series(cs).replace(-1, None)})
    filled = frame.select(
        "ac", _row=pl.when(pl.col("cs").is_not_null()).then("row"), _cs="cs"
    ).select(pl.col("_row", "_cs").fill_null(strategy="forward").over("ac"))
    known = filled["_cs"].is_not_null().to_numpy()
    code = filled["_cs"].fill_null(0).to_numpy()
    renamed = known[1:] & known[:-1] & (code[1:] != code[:-1])
    new = np.r_[True, (ac[1:] != ac[:-1]) | (np.diff(ts) / 1e6 > CFG.gap_split_s) | renamed]
    return new, filled["_row"].fill_null(-1).to_numpy()


def _flight_starts(rows, ac, ts, cs):
    """The kernel's outputs, written into arrays filled with values it must overwrite."""
    new, callsign_row = np.ones(rows.size, dtype=bool), np.full(rows.size, 99, dtype=np.int64)
    kernels.flight_starts(rows, ac, ts, cs, CFG.gap_split_s, new, callsign_row)
    return new, callsign_row


def test_flight_starts_equal_the_polars_split():
    rng = np.random.default_rng(7)
    n = 5_000
    ac = np.sort(rng.integers(0, 30, n)).astype(np.uint32)
    ts = np.cumsum(rng.choice([1, 10, 1801, 1800], n, p=[0.6, 0.3, 0.05, 0.05])) * 1_000_000
    cs = rng.choice([-1, -1, 0, 1, 2], n).astype(np.int64)
    new, callsign_row = _flight_starts(np.arange(n), ac, ts, cs)
    want_new, want_row = _split_oracle(ac, ts, cs)
    assert want_new.sum() > 500 and (want_row < 0).sum() > 10
    np.testing.assert_array_equal(new, want_new)
    np.testing.assert_array_equal(callsign_row, want_row)


def test_flight_starts_at_a_gap_a_rename_and_another_aircraft_only():
    ac = np.array([0, 0, 0, 0, 0, 0, 1], dtype=np.uint32)
    ts = np.array([0, 1, 2, 1803, 1804, 1805, 1806], dtype=np.int64) * 1_000_000  # 1801 s of silence before row 3
    cs = np.array([-1, 4, -1, 4, 5, -1, -1], dtype=np.int64)  # none, then 4 (no new flight), 5 (a new one)
    new, callsign_row = _flight_starts(np.arange(7), ac, ts, cs)
    assert new.tolist() == [True, False, False, True, True, False, True]
    assert callsign_row.tolist() == [-1, 1, 1, 3, 4, 4, -1]
