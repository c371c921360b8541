"""The ingest's row rules and flight split as numba kernels: one pass each over the rows in (aircraft, ts) order where
the polars rules made ~70 collects (issue 2: the chain on the bundled file >= 20x `traffic`); and the 20 s grid's
interpolation (`grid_rows`, `interpolate`: 8.6 -> 5.0 ms for the bundled file's tracks, 23 -> 10 ms for 558 flights).

Results are those of the polars/numpy rules they replaced, bit for bit: the same comparisons and the same float
operations in the same order (tests/aviation/test_ingest_kernels.py, test_ingest_fast_paths.py). numba caches the machine code beside this
file; a kernel's cache is invalidated only by a change of this file, so it imports nothing from the project and
takes the constants it uses as arguments (models/jit.py).
"""

import numpy as np

from models.jit import jit

# reason codes of rejected rows: 0 is kept, code c is REASONS[c - 1] (ingest writes them as strings)
REASONS = ("missing_value", "duplicate_row", "on_ground", "out_of_range", "repeated_position", "speed_spike", "short_segment")
MISSING_VALUE, DUPLICATE_ROW, ON_GROUND, OUT_OF_RANGE, REPEATED_POSITION, SPEED_SPIKE, SHORT_SEGMENT = range(1, len(REASONS) + 1)
FAST, STEEP = 1, 2  # a leg's bits in `speed_spikes`
MAX_MERGED_RUNS = 16  # an aircraft's runs of time-ordered rows merged stretch by stretch; more: a sort (`_merge_runs`)


@jit
def aircraft_time_order(ac, ts_us, missing, ts_lo, ts_hi, reason):
    """The rules that look at a row alone, then the rows they keep in (aircraft, ts, row) order.

    A row with a missing value gets MISSING_VALUE, one with a time outside [ts_lo, ts_hi) OUT_OF_RANGE (a decoding
    error, which would overflow the later time differences), written into reason[row] (all 0 before). The others: a
    counting sort by aircraft code (stable: rows stay in file order), then a stable sort by time of each aircraft whose
    rows are not already in time order (`_merge_runs`; state vectors come in runs of one aircraft in time order: the
    bundled file's aircraft have 1-11 such runs, 8 of its 49 just one)."""
    n_aircraft = 0
    for r in range(ac.size):
        if missing[r]:
            reason[r] = MISSING_VALUE
        elif not ts_lo <= ts_us[r] < ts_hi:
            reason[r] = OUT_OF_RANGE
        else:
            n_aircraft = max(n_aircraft, ac[r] + 1)
    first = np.zeros(n_aircraft + 1, dtype=np.int64)  # first[a]: aircraft a's first slot
    for r in range(ac.size):
        if reason[r] == 0:
            first[ac[r] + 1] += 1
    first = np.cumsum(first)
    slot = first[:-1].copy()
    order = np.empty(first[-1], dtype=np.int64)
    for r in range(ac.size):
        if reason[r] == 0:
            order[slot[ac[r]]] = r
            slot[ac[r]] += 1
    for a in range(n_aircraft):
        _merge_runs(order[first[a] : first[a + 1]], ts_us)
    return order


@jit
def _merge_runs(rows, ts_us):
    """Sort `rows` (increasing) by ts_us[row] in place, stably, by merging its runs of non-decreasing times (none: no
    work) in one pass: the run whose next row comes first (least time, then the earliest run) gives every row up to
    the other runs' next times at once, found by binary search. An aircraft's runs interleave in long stretches (41 of
    the bundled file's 49 aircraft have 2-11 runs, its hours stored out of order; 196 stretches in all: 1.9 -> 0.8 ms
    for all aircraft against merging run pairs row by row). Each stretch looks at every run, so with more than
    MAX_MERGED_RUNS (rows in no time order: newest first, shuffled, feeds interleaved) a stable sort does it instead."""
    starts = [0]
    for k in range(1, rows.size):
        if ts_us[rows[k]] < ts_us[rows[k - 1]]:
            starts.append(k)
    if len(starts) == 1:
        return
    n_runs = len(starts)
    t = ts_us[rows]
    if n_runs > MAX_MERGED_RUNS:  # stable: equal times keep their rows' (increasing) order
        rows[:] = rows[np.argsort(t, kind="mergesort")]
        return
    at = np.array(starts)  # each run's next row
    end = np.array(starts[1:] + [rows.size])
    out = np.empty_like(rows)
    k = 0
    while k < rows.size:
        c = -1
        for i in range(n_runs):
            if at[i] < end[i] and (c < 0 or t[at[i]] < t[at[c]]):
                c = i
        stop = end[c]  # c's rows before an earlier run's next time, up to (ties included) a later run's: stable
        for i in range(n_runs):
            if i < c and at[i] < end[i]:
                stop = min(stop, at[c] + np.searchsorted(t[at[c] : stop], t[at[i]], side="left"))
            elif i > c and at[i] < end[i]:
                stop = min(stop, at[c] + np.searchsorted(t[at[c] : stop], t[at[i]], side="right"))
        out[k : k + stop - at[c]] = rows[at[c] : stop]
        k += stop - at[c]
        at[c] = stop
    rows[:] = out


@jit(nogil=True)
def point_rules(order, ac, ts_us, lat, lon, alt_m, onground, groundspeed_mps, pos_us, has_pos, min_alt_m, max_alt_m,
                max_speed_mps, reason):
    """Rows `order` (no missing value, in (aircraft, ts, row) order) -> the rows that pass, in that order, moved to the
    head of `order` (returned as a view of it: no new array, whose pages would cost about what this pass does); writes
    the code of each rejected row into reason[row].

    Two stages. The first tests each row against the previous row of `order` (duplicate: same aircraft and ts, so
    the first of equal rows is kept), then on its own (on the ground; out of range, a null ground speed counting as
    0). The second sees only the rows the first kept: a repeated position is the previous kept row's position time
    again (NaN equals NaN, as in polars), or, where the row has no position time, its latitude and longitude again."""
    n = 0
    last = -1  # the previous row that passed the first stage
    before = -1  # the previous row of `order` (its slot may have been overwritten by then)
    for k in range(order.size):
        r = order[k]
        prev, before = before, r
        if prev >= 0 and ac[r] == ac[prev] and ts_us[r] == ts_us[prev]:
            reason[r] = DUPLICATE_ROW
            continue
        if onground[r]:
            reason[r] = ON_GROUND
            continue
        if not (-90.0 <= lat[r] <= 90.0 and -180.0 <= lon[r] <= 180.0 and min_alt_m <= alt_m[r] <= max_alt_m) or (
            groundspeed_mps[r] > 2 * max_speed_mps
        ):
            reason[r] = OUT_OF_RANGE
            continue
        p, last = last, r
        if p >= 0 and ac[p] == ac[r]:
            if has_pos[r]:
                repeated = has_pos[p] and (pos_us[r] == pos_us[p] or (pos_us[r] != pos_us[r] and pos_us[p] != pos_us[p]))
            else:
                repeated = lat[r] == lat[p] and lon[r] == lon[p]
            if repeated:
                reason[r] = REPEATED_POSITION
                continue
        order[n] = r
        n += 1
    return order[:n]


@jit(nogil=True)
def speed_spikes(rows, ac, ts_us, lat, lon, alt_m, max_speed_mps, max_climb_mps, earth_radius_m, reason):
    """Rows `rows` (in (aircraft, ts) order) -> those that pass, in that order, moved to the head of `rows` (returned
    as a view of it); writes SPEED_SPIKE into reason[row] of an isolated point the aircraft could not have reached and
    left again: both legs (from the previous and to the next row of the same aircraft) too fast, or both too steep.

    A leg's time has a 1 s floor: OpenSky timestamps are whole seconds, a 0 s step would make every move "infinite".
    Climb is compared as a rate (`> c * dt` rounds otherwise at the limit). A cheap bound clears nearly every leg: with
    cos x <= 1 - x²/2 + x⁴/24 (0.2 % high at 60°) in place of the cosine a leg only gets longer, so a leg possible
    under it is possible; the few others get the equirectangular distance (within 0.5 % of great-circle under
    500 km) with its trigonometry."""
    n = rows.size
    leg = np.zeros(n, dtype=np.uint8)  # of the leg from row i - 1 to row i: FAST | STEEP bits
    reach_deg_per_s = np.degrees(max_speed_mps / earth_radius_m)
    x2_per_lat2 = (np.pi / 360) ** 2  # (mean latitude in radians)² per (lat1 + lat2)²
    for i in range(1, n):
        a, b = rows[i - 1], rows[i]
        if ac[a] != ac[b]:
            continue
        dt = max((ts_us[b] - ts_us[a]) / 1e6, 1.0)
        if np.abs(alt_m[b] - alt_m[a]) / dt > max_climb_mps:
            leg[i] = STEEP
        dlon = np.abs(lon[b] - lon[a])
        dlon = min(dlon, 360.0 - dlon)  # the shorter way round
        x2 = (lat[b] + lat[a]) ** 2 * x2_per_lat2
        dlon *= 1 - x2 * (0.5 - x2 / 24)
        reach_deg = dt * reach_deg_per_s
        if (lat[b] - lat[a]) ** 2 + dlon**2 > reach_deg**2 * (1 - 1e-9):
            dx = np.radians((lon[b] - lon[a] + 180.0) % 360.0 - 180.0) * np.cos(np.radians((lat[a] + lat[b]) / 2))
            if earth_radius_m * np.sqrt(np.radians(lat[b] - lat[a]) ** 2 + dx**2) / dt > max_speed_mps:
                leg[i] |= FAST
    m = 0
    for i in range(n):  # slot m <= i: rows[i] is read before it can be overwritten
        if 0 < i < n - 1 and leg[i] & leg[i + 1]:  # the same bit in and out: both too fast or both too steep
            reason[rows[i]] = SPEED_SPIKE
        else:
            rows[m] = rows[i]
            m += 1
    return rows[:m]


@jit(nogil=True)
def flight_starts(rows, ac, ts_us, cs, gap_split_s, new, callsign_row):
    """Rows `rows` (kept, in (aircraft, ts) order) -> new[k]: whether rows[k] starts a flight; callsign_row[k]: the row
    whose callsign it takes: its own, else the aircraft's last one before it, else -1 (both written into the caller's
    arrays, as long as `rows`).

    A flight starts at an aircraft's first row, after a silence longer than gap_split_s, and where the (carried
    forward) callsign code `cs` (-1: none) changes from one known callsign to another."""
    for k in range(rows.size):
        r = rows[k]
        first = k == 0 or ac[r] != ac[rows[k - 1]]
        carried = -1 if first else callsign_row[k - 1]
        callsign_row[k] = r if cs[r] >= 0 else carried
        renamed = cs[r] >= 0 and carried >= 0 and cs[r] != cs[carried]
        new[k] = first or (ts_us[r] - ts_us[rows[k - 1]]) / 1e6 > gap_split_s or renamed


@jit
def grid_rows(t_us, first, end, grid_first, grid_us):
    """The row of each grid point: its flight's last row at or before its time. A flight's rows are first[f]:end[f]
    (times strictly increasing), its grid points grid_first[f]:grid_first[f + 1] (increasing, within the flight's
    times); a binary search among the rows after the previous grid point's."""
    row = np.empty(grid_us.size, dtype=np.int64)
    for f in range(first.size):
        lo = first[f]
        for g in range(grid_first[f], grid_first[f + 1]):
            lo += np.searchsorted(t_us[lo : end[f]], grid_us[g], side="right") - 1
            row[g] = lo
    return row


@jit(nogil=True)
def interpolate(t_us, first, end, grid_first, grid_us, row, values, turn, out):
    """Each flight's valid (not NaN) values, linear in time, at its grid times -> out (`grid_rows`' flights, grid
    and rows).

    np.interp's arithmetic to the bit: the left value on an exact hit, else slope times offset plus the left value.
    Outside a flight's first and last valid value there is nothing to interpolate from: NaN. With turn > 0 (360) an
    angle, turned along the shorter arc (not wrapped). The last valid row at or before a grid point and the next
    valid one after it only move forward: each row is looked at about once."""
    for f in range(first.size):
        seen, last, nxt = first[f] - 1, -1, first[f]  # rows up to `seen` looked at; the last valid of them; next valid after `last`
        for g in range(grid_first[f], grid_first[f + 1]):
            r = row[g]
            while r > seen and values[r] != values[r]:
                r -= 1
            if r > seen:
                last = r
            seen = row[g]
            if last < 0:
                out[g] = np.nan
                continue
            dx = grid_us[g] - t_us[last]
            if dx == 0:
                out[g] = values[last]
                continue
            nxt = max(nxt, last + 1)
            while nxt < end[f] and values[nxt] != values[nxt]:
                nxt += 1
            if nxt >= end[f]:
                out[g] = np.nan
                continue
            rise = values[nxt] - values[last]
            if turn > 0:
                rise = (rise + turn / 2) % turn - turn / 2
            out[g] = rise / float(t_us[nxt] - t_us[last]) * float(dx) + values[last]
