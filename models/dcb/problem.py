"""The DCB problem as arrays: sector entries of all flights, hourly capacities, hotspots and the reward.

A ground delay d_i (whole minutes) shifts every entry of flight i by d_i. A hotspot is a sector-hour
whose entry count exceeds its capacity (thesis §5.3). Everything here is vectorised over all entries; the
evaluation and the thesis reward, which the learners call at every episode step, are numba kernels
(models/dcb/kernels.py: one pass over the entries instead of ~15 numpy calls on small arrays).

Reward of flight-agent i (Eq 5.2-5.4), λ = 20:

    r_i = C_i - λ · DC_i
    C_i = -81 · TDC_i  if TDC_i > 0   (TDC_i: minutes flight i spends in sectors during their hotspot hours;
          C_PLUS        if TDC_i = 0    81 €/min is Europe's average strategic delay cost. The thesis prints
                                        "81 × TDC"; as congestion must be penalised it enters with a minus.)
    DC_i = SDC(d_i, class_i) = d_i · cost_class / 81   (delay in average-cost minutes, see DELAY_COST_EUR_PER_MIN)

Beyond the thesis (options of the learners, docs/dcb.md): `difference_reward`, each flight's own change
of the day's total of Eq 5.2, `overload_reward`, the same for the day's entries beyond capacity, and
`movers`, the extra component of the extended local state.
"""

from dataclasses import dataclass, field
from datetime import timedelta

import numpy as np
import polars as pl

from models.dcb import kernels

LAMBDA = 20.0  # Eq 5.2 trade-off between congestion and delay cost (thesis §5.6.2)
AVG_DELAY_COST_EUR_PER_MIN = 81.0  # Eq 5.3 coefficient: Europe's average strategic delay cost per minute
C_PLUS = 100.0  # Eq 5.3 reward for a flight in no hotspot ("a large positive constant"; value is ours)
REGULATED_MIN = 4  # delays under 4 minutes are ignored in avg delay and regulated flights (thesis §5.6.1)

# Strategic (planned-ahead) ground delay cost per minute by aircraft class. Our documented assumption,
# scaled around the thesis's 81 €/min European average in the proportions of aircraft size; ADS-B
# demand has no aircraft type, so its flights are "unknown" and cost the average.
DELAY_COST_EUR_PER_MIN = {"turboprop": 40.0, "regional_jet": 60.0, "narrowbody": 81.0, "widebody": 155.0, "unknown": 81.0}
_CLASS_PREFIXES = {
    "widebody": ("A33", "A34", "A35", "A38", "B74", "B76", "B77", "B78", "MD11", "IL96", "A30"),
    "turboprop": ("AT4", "AT7", "DH8", "SF34", "JS41", "D328", "F50", "B190", "C208", "PC12"),
    "regional_jet": ("CRJ", "E13", "E14", "E17", "E19", "E29", "E75", "RJ", "F70", "F100", "SU95", "BCS1"),
    "narrowbody": ("A31", "A32", "A2", "B73", "B37", "B38", "B39", "B75", "BCS3", "MD8", "MD9", "C919"),
}


def aircraft_class(aircraft_type: pl.Expr) -> pl.Expr:
    """ICAO type designator (e.g. A320, B77W) -> delay cost class; null or unlisted -> unknown."""
    expr = pl.lit("unknown")
    for cls, prefixes in reversed(list(_CLASS_PREFIXES.items())):
        expr = pl.when(pl.any_horizontal(aircraft_type.str.starts_with(p) for p in prefixes).fill_null(False)).then(pl.lit(cls)).otherwise(expr)
    return expr


@dataclass
class Evaluation:
    """Hotspot picture for one delay vector."""

    counts: np.ndarray  # [sector*hour] entry count
    hot: np.ndarray  # [sector*hour] bool, count > capacity
    entry_key: np.ndarray  # [entry] sector*hours + hour of the (delayed) entry
    entry_hot: np.ndarray  # [entry] bool, the entry falls in a hotspot
    hotspots_per_flight: np.ndarray  # [flight] h_i
    congested_min: np.ndarray  # [flight] TDC_i
    hot_key: np.ndarray  # [hot entry] entry_key of the entries in a hotspot (entry order)
    hot_flight: np.ndarray  # [hot entry] their flights

    @property
    def hotspots(self) -> int:
        return int(self.hot.sum())


@dataclass
class _Entries:
    """Per-entry arrays of a subset of the entries, gathered once."""

    flight: np.ndarray
    key_base: np.ndarray  # sector · n_hours
    whole_min: np.ndarray  # ⌊entry minute⌋
    dur_min: np.ndarray
    within_hour: bool = False  # delays are known to lie in [0, 60] (the relevant entries with MaxDelay <= 60)
    shifted: np.ndarray = field(init=False, default=None)  # within_hour: 64 · (key_base + hour) + minute in the hour + 4

    def __post_init__(self):
        # for d in [0, 60] an entry at minute r = m mod 60 of its hour moves on at most one hour, and
        # ⌊(r + d) / 60⌋ = ⌊(r + 4 + d) / 64⌋ (r + d < 120): the key is a shift of a per-entry constant plus d,
        # cheaper than the integer division; unused otherwise (an empty array keeps the kernels' argument types)
        self.shifted = 64 * (self.key_base + self.whole_min // 60) + self.whole_min % 60 + 4 if self.within_hour else self.key_base[:0]

    def keys(self, delay_min: np.ndarray) -> np.ndarray:
        return kernels.entry_keys(self.shifted, self.key_base, self.whole_min, self.flight, delay_min, self.within_hour)


class DCBProblem:
    """Flights, their sector entries (minutes since 00:00 UTC of the first day) and hourly capacities."""

    def __init__(self, entries: pl.DataFrame, capacity_per_h: dict[str, int], flights: pl.DataFrame, max_delay_min: int = 60):
        """entries: flight_id, sector, entry_ts, exit_ts; flights: flight_id, aircraft_class (one row per flight)."""
        self.flight_ids = flights["flight_id"].to_list()
        self.sectors = sorted(capacity_per_h)
        self.max_delay_min = max_delay_min
        day0 = entries["entry_ts"].min().replace(hour=0, minute=0, second=0, microsecond=0)
        e = entries.join(flights.select("flight_id", _f=pl.int_range(pl.len())), on="flight_id", how="inner").join(
            pl.DataFrame({"sector": self.sectors, "_s": np.arange(len(self.sectors))}), on="sector", how="inner"
        )
        if e.height != entries.height:
            raise ValueError(f"{entries.height - e.height} entries name a flight or sector the problem does not know")
        self.day0 = day0
        self.entry_flight = e["_f"].to_numpy()
        self.entry_sector = e["_s"].to_numpy()
        self.entry_min = ((e["entry_ts"] - day0).dt.total_seconds(fractional=True) / 60).to_numpy()
        self.entry_dur_min = ((e["exit_ts"] - e["entry_ts"]).dt.total_seconds(fractional=True) / 60).to_numpy()
        # whole delays only: ⌊(m + d)/60⌋ = ⌊(⌊m⌋ + d)/60⌋, so keys need only integer arithmetic
        self.entry_whole_min = np.floor(self.entry_min).astype(np.int64)
        self.n_flights, self.n_sectors = len(self.flight_ids), len(self.sectors)
        # the hour grid covers two days (FCFS delays are not capped at MaxDelay) and always one spare
        # hour after the last reachable one, so that k1 + 1 below stays inside its sector's block
        self.n_hours = max(int((self.entry_min.max() + max_delay_min) // 60) + 2, 48)
        self.sector_capacity = np.array([capacity_per_h[s] for s in self.sectors], dtype=np.int64)
        self.capacity = np.repeat(self.sector_capacity, self.n_hours)  # [sector*hour], constant over the day
        self.relevant = self._entries_that_can_be_hot()
        # the learners evaluate every step: their entries' arrays gathered once, not at every call; every caller keeps
        # delays within [0, MaxDelay] (the entries are chosen for those), which lets the keys be a shift when MaxDelay <= 60
        self.relevant_entries = self._entry_arrays(self.relevant, within_hour=max_delay_min <= 60)
        self._all_entries = self._entry_arrays(slice(None))
        cost = flights["aircraft_class"].replace_strict(DELAY_COST_EUR_PER_MIN, return_dtype=pl.Float64).to_numpy()
        self.delay_weight = cost / AVG_DELAY_COST_EUR_PER_MIN  # DC per minute of delay, in average-cost minutes
        self.delay_cost = LAMBDA * self.delay_weight  # λ · DC_i per minute of delay (Eq 5.2), once, not every step

    def _entries_that_can_be_hot(self) -> np.ndarray:
        """Entries that can land in a sector-hour that some delays in [0, MaxDelay] overload.

        The others can never create or sit in a hotspot, so learning evaluates only these (exact:
        identical hotspots, h_i and TDC_i; only the counts of never-hot sector-hours differ). An entry
        reaches the keys k0..k1 (consecutive hours of one sector); `most` counts, per key, every entry
        that can reach it, via a difference array."""
        k0, k1 = (self.entry_keys(np.full(self.n_flights, d)) for d in (0, self.max_delay_min))
        diff = np.bincount(k0, minlength=self.capacity.size + 1) - np.bincount(k1 + 1, minlength=self.capacity.size + 1)
        most = np.cumsum(diff)[:-1]
        over = np.concatenate([[0], np.cumsum(most > self.capacity)])  # over[k]: overloadable keys before k
        return np.nonzero(over[k1 + 1] - over[k0] > 0)[0]

    def _entry_arrays(self, idx, within_hour: bool = False) -> "_Entries":
        return _Entries(self.entry_flight[idx], self.entry_sector[idx] * self.n_hours, self.entry_whole_min[idx], self.entry_dur_min[idx], within_hour)

    def entry_keys(self, delay_min: np.ndarray, idx=slice(None)) -> np.ndarray:
        """key = sector · n_hours + ⌊(entry minute + d_i) / 60⌋ of every entry (whole-minute delays)."""
        return self._entry_arrays(idx).keys(delay_min)

    def kernel_entries(self, all_entries: bool = False) -> tuple:
        """`kernels.evaluate`'s arguments after the delays: the entries' arrays, capacity, grid and the largest delay they
        serve (all entries: any delay that keeps them on the grid)."""
        e, max_delay = (self._all_entries, 60 * self.n_hours) if all_entries else (self.relevant_entries, self.max_delay_min)
        return e.shifted, e.key_base, e.whole_min, e.flight, e.dur_min, e.within_hour, self.capacity, self.n_hours, self.n_flights, max_delay

    def evaluate(self, delay_min: np.ndarray, all_entries: bool = False) -> Evaluation:
        """Hotspots for a delay vector; `all_entries` also counts entries that can never be in a hotspot. Without it,
        delays must lie in [0, MaxDelay]: the relevant entries are chosen for those, and their keys are computed
        for them only (a shift when MaxDelay <= 60). One line for delays outside that range, or with all_entries for an
        entry that would reach the grid's spare last hour or leave its sector's hours."""
        status, *arrays = kernels.evaluate(delay_min, *self.kernel_entries(all_entries), all_entries, True)
        if status == 2:
            limit = (f"the problem's {self.n_hours}-hour grid" if all_entries
                     else f"[0, MaxDelay {self.max_delay_min}] min, the range the learners' evaluation is made for")
            raise ValueError(f"delays {delay_min.min()}..{delay_min.max()} min: outside {limit}")
        if status == 1:
            raise ValueError(f"delays of up to {delay_min.max()} min run past the problem's {self.n_hours}-hour grid")
        return Evaluation(*arrays)

    def movers(self, delay_min: np.ndarray, ev: Evaluation) -> np.ndarray:
        """[flight] 1 if one of its hot entries is among the `demand - capacity` entries of that hotspot
        closest to the end of their hour (the cheapest to push out of it), else 0 - the extended state's
        extra component. A flight entering at hh:58 needs 2 min of delay to leave its hotspot hour, one
        at hh:05 needs 55; the thesis state (d_i, h_i) does not say which of a hotspot's flights these are."""
        idx = self.relevant[ev.entry_hot]
        key, flight = ev.entry_key[ev.entry_hot], self.entry_flight[idx]
        to_leave = 60 - (self.entry_min[idx] + delay_min[flight]) % 60
        order = np.lexsort((flight, to_leave, key))  # ties: lower flight index first (deterministic)
        ks = key[order]
        rank = np.arange(ks.size) - np.searchsorted(ks, ks, side="left")
        excess = ev.counts[ks] - self.capacity[ks]
        return np.bincount(flight[order][rank < excess], minlength=self.n_flights).clip(max=1)

    def reward(self, delay_min: np.ndarray, ev: Evaluation, c_plus: float = C_PLUS) -> np.ndarray:
        """Eq 5.2-5.4 for every flight (c_plus: C₊, the reward of a flight in no hotspot)."""
        return kernels.thesis_reward(ev.congested_min, self.delay_cost, delay_min, AVG_DELAY_COST_EUR_PER_MIN, c_plus)

    def difference_reward(self, added_min: np.ndarray, before: Evaluation, after: Evaluation) -> np.ndarray:
        """D_i = G(z) - G(z_-i): what flight i's own action changed in the day's congestion and delay cost,
        G = -81 · Σ_i TDC_i - λ · Σ_i DC_i (Eq 5.2 summed over flights, C₊ left out), against i holding
        instead while everybody else does what they did (Wolpert & Tumer's difference reward). The thesis
        reward charges every flight of a hotspot until it clears, so all of them learn to flee; D_i pays
        only for moves that were needed.

        A flight that holds gets 0. One that delays pays λ · its added delay [average-cost min] and, for
        each entry that changed sector-hour, is credited the congestion its leaving removed from the old
        one (its own minutes there, or the whole hotspot's minutes if it was the entry that cleared it)
        and charged what its arrival added to the new one. Exact for one entry per flight and sector-hour."""
        e = self.relevant_entries
        change = before.entry_key != after.entry_key
        k0, k1 = before.entry_key[change], after.entry_key[change]
        dur, count = e.dur_min[change], after.counts
        inside = np.bincount(after.entry_key, weights=e.dur_min, minlength=self.capacity.size)  # minutes per sector-hour
        cap0, cap1 = self.capacity[k0], self.capacity[k1]
        removed = (count[k0] + 1 > cap0) * (inside[k0] + dur) - (count[k0] > cap0) * inside[k0]
        added = (count[k1] > cap1) * inside[k1] - (count[k1] - 1 > cap1) * (inside[k1] - dur)
        congestion = np.bincount(e.flight[change], weights=removed - added, minlength=self.n_flights)
        return AVG_DELAY_COST_EUR_PER_MIN * congestion - self.delay_cost * added_min

    def overload_reward(self, added_min: np.ndarray, before: Evaluation, after: Evaluation) -> np.ndarray:
        """The difference reward of G = -P · Σ_k max(0, count_k - capacity_k) - λ · Σ_i DC_i: the day's overload
        (entries beyond capacity, summed over sector-hours) instead of its congested minutes.

        `difference_reward` credits a flight that leaves a hotspot with its own minutes there even when the
        hotspot stays overloaded, so every flight of a hotspot gains by fleeing: the lockstep over-delay
        (docs/dcb.md, "What we learned"). Here leaving pays P only if it lowered the overload (the hour still had an entry too many
        with the flight in it) and arriving costs P if it raised it; a second flight leaving an hour the first
        has already cleared pays its delay and earns nothing. P = 2 · λ · MaxDelay: resolving an excess entry is always worth more
        than any admissible delay. Exact for one entry per flight and sector-hour."""
        e = self.relevant_entries
        change = before.entry_key != after.entry_key
        k0, k1, count = before.entry_key[change], after.entry_key[change], after.counts
        lowered = (count[k0] + 1 > self.capacity[k0]).astype(np.float64) - (count[k1] > self.capacity[k1])
        penalty = 2 * LAMBDA * self.max_delay_min
        return penalty * np.bincount(e.flight[change], weights=lowered, minlength=self.n_flights) - self.delay_cost * added_min


def base_capacities(entries: pl.DataFrame, sectors: pl.DataFrame) -> dict[str, int]:
    """Hourly capacity per sector before case scaling.

    A sector's base capacity is its `capacity_per_h` from the sector file or, where none is given,
    its peak hourly entry count in the undelayed demand (no open capacity data exists; 1 for a
    sector no flight enters)."""
    peak = (
        entries.group_by("sector", hour=pl.col("entry_ts").dt.truncate("1h")).len()
        .group_by("sector").agg(peak=pl.col("len").max())
    )
    base = sectors.select("sector", "capacity_per_h").join(peak, on="sector", how="left").with_columns(
        base=pl.coalesce("capacity_per_h", "peak", pl.lit(1, pl.UInt32).cast(pl.Int64))
    )
    return dict(base.select("sector", "base").iter_rows())


def scaled_capacities(base: dict[str, int], scale: float) -> dict[str, int]:
    """One evaluation case: capacity = max(1, floor(scale * base)). Scales < 1 create hotspots."""
    return {s: max(1, int(np.floor(scale * b + 1e-9))) for s, b in base.items()}


def hotspot_table(problem: DCBProblem, delay_min: np.ndarray) -> pl.DataFrame:
    """Demand and capacity per sector-hour (all sector-hours with demand), with the hotspot flag."""
    ev = problem.evaluate(delay_min, all_entries=True)
    key = np.nonzero(ev.counts)[0]
    return pl.DataFrame({
        "sector": np.asarray(problem.sectors)[key // problem.n_hours],
        "hour": [problem.day0 + timedelta(hours=int(h)) for h in key % problem.n_hours],
        "demand": ev.counts[key].astype(np.int64),
        "capacity": problem.capacity[key],
    }).with_columns(pl.col("hour").cast(pl.Datetime("us", "UTC")), is_hotspot=pl.col("demand") > pl.col("capacity"))
