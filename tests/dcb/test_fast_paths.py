"""The learners' fast paths give exactly what the straightforward versions they replaced gave.

`evaluate` (integer keys, entry arrays gathered once, per-flight sums over hot entries only) against
the former full evaluation (float keys, weighted sums over every entry), and its keys within the hour (a
shift) against the integer division; `peer_edges` (now a kernel) against np.unique; and whole training runs against delays recorded with the code before the speed-ups (same seed -> same delays, bit for bit): RECORDED before
the first speed-ups (docs/history/dcb.md, first round), RECORDED_CMARL before CoordinatedQ's split hash, stacked tables and graph reuse.
"""

import numpy as np
import polars as pl
import pytest

from models.dcb.cmarl import peer_edges
from models.dcb.experiment import build_problem
from models.dcb.train import train


def former_evaluate(p, delay_min, all_entries):
    """The evaluation as it was before the speed-ups: float minutes, bincount weighted over every entry."""
    idx = slice(None) if all_entries else p.relevant
    key = p.entry_sector[idx] * p.n_hours + ((p.entry_min[idx] + delay_min[p.entry_flight[idx]]) // 60).astype(np.int64)
    counts = np.bincount(key, minlength=p.capacity.size)
    hot = counts > p.capacity
    entry_hot = hot[key]
    flight = p.entry_flight[idx]
    h = np.bincount(flight, weights=entry_hot, minlength=p.n_flights).astype(np.int64)
    tdc = np.bincount(flight, weights=entry_hot * p.entry_dur_min[idx], minlength=p.n_flights)
    return counts, hot, key, entry_hot, h, tdc


def former_peer_edges(ev, flight_of_entry, n_flights):
    hot = np.nonzero(ev.entry_hot)[0]
    key, flight = ev.entry_key[hot], flight_of_entry[hot]
    same = key[:, None] == key[None, :]  # every pair of hot entries in one sector-hour
    a, b = np.nonzero(np.triu(same, 1))
    i, j = np.minimum(flight[a], flight[b]), np.maximum(flight[a], flight[b])
    pair = np.unique(i[i != j] * n_flights + j[i != j])
    return pair // n_flights, pair % n_flights


@pytest.mark.parametrize("all_entries", [False, True])
def test_evaluate_equals_the_former_full_evaluation(small_case, all_entries):
    p, rng = small_case, np.random.default_rng(0)
    hot_seen = 0
    for _ in range(60):
        # delays over the whole range, and mostly-zero vectors like the early steps of an episode
        delay = rng.integers(0, p.max_delay_min + 1, p.n_flights) * (rng.random(p.n_flights) < rng.choice([0.05, 0.5, 1.0]))
        ev = p.evaluate(delay, all_entries=all_entries)
        fast = (ev.counts, ev.hot, ev.entry_key, ev.entry_hot, ev.hotspots_per_flight, ev.congested_min)
        for got, want in zip(fast, former_evaluate(p, delay, all_entries)):
            assert got.dtype == want.dtype and np.array_equal(got, want)
        hot_seen += ev.hotspots
        i, j, degree, pair = peer_edges(ev, p.n_flights)
        fi, fj = former_peer_edges(ev, p.entry_flight[p.relevant if not all_entries else slice(None)], p.n_flights)
        assert np.array_equal(i, fi) and np.array_equal(j, fj) and np.array_equal(pair, i * p.n_flights + j)
        assert np.array_equal(degree, np.bincount(np.concatenate([fi, fj]), minlength=p.n_flights))
    assert hot_seen > 0  # the comparison covered hotspots, not only empty pictures


@pytest.mark.parametrize("max_delay", [60, 61, 90])
def test_relevant_keys_equal_the_integer_division_at_every_admissible_delay(swiss_tables, max_delay):
    """The relevant entries' keys (a shift when MaxDelay <= 60, else the division) equal ⌊(m + d) / 60⌋ at every delay
    in [0, MaxDelay], entries at hh:00 and hh:59 (the identity's tight edge) among them."""
    sectors, flights, entries = swiss_tables
    first = entries.group_by("flight_id").agg(pl.col("entry_ts").min())
    keep = first.filter(pl.col("entry_ts").dt.hour().is_between(9, 10))["flight_id"].implode()
    p = build_problem(entries.filter(pl.col("flight_id").is_in(keep)), sectors, flights.filter(pl.col("flight_id").is_in(keep)), 0.9, max_delay)
    e = p.relevant_entries
    assert e.within_hour == (max_delay <= 60) and (e.whole_min % 60 == 0).any() and (e.whole_min % 60 == 59).any()
    for d in range(max_delay + 1):
        keys = e.keys(np.full(p.n_flights, d))
        assert keys.dtype == np.int64 and np.array_equal(keys, e.key_base + (e.whole_min + d) // 60)


# (total delay, Σ delay_i · (i + 1), source) of train(small_case, method, seed=1, episodes=20), recorded
# with the code before the speed-ups (per-call gathers, np.unique, max(axis=1), float keys)
RECORDED = {
    ("MIRL", "thesis", "thesis"): (171, 16310, "best_episode"),
    ("CMARL", "thesis", "thesis"): (166, 16688, "best_episode"),
    ("HCMARL", "thesis", "thesis"): (103, 10282, "greedy"),
    ("HCMARL", "extended", "difference"): (74, 7026, "greedy"),
    ("sHMIRL", "extended", "difference"): (23, 2245, "greedy"),
}


@pytest.mark.parametrize("method, state, reward", list(RECORDED))
def test_same_delays_as_before_the_speed_ups(small_case, method, state, reward):
    r = train(small_case, method, seed=1, episodes=20, state=state, reward=reward, readout="best_episode")
    d = r.delay_min
    assert (int(d.sum()), int((d * np.arange(1, d.size + 1)).sum()), r.source) == RECORDED[(method, state, reward)]


# the same fingerprint, recorded with CoordinatedQ as it was before the split hash, the stacked ground +
# abstract tables and the graph reuse (one hash per lookup, graph and prior lookups rebuilt every step)
RECORDED_CMARL = {
    ("CMARL", "thesis", "thesis", 0): (164, 15924, "best_episode"),
    ("CMARL", "extended", "difference", 0): (154, 15019, "best_episode"),
    ("HCMARL", "thesis", "thesis", 0): (134, 12392, "greedy"),
    ("HCMARL", "extended", "difference", 0): (90, 9198, "greedy"),
}


@pytest.mark.parametrize("method, state, reward, seed", list(RECORDED_CMARL))
def test_coordinated_learners_same_delays_as_before_the_restructuring(small_case, method, state, reward, seed):
    r = train(small_case, method, seed=seed, episodes=20, state=state, reward=reward, readout="best_episode")
    d = r.delay_min
    assert (int(d.sum()), int((d * np.arange(1, d.size + 1)).sum()), r.source) == RECORDED_CMARL[(method, state, reward, seed)]


def test_full_day_hcmarl_same_delays_as_before_the_restructuring(swiss_tables):
    """The whole day (1,244 flights, graphs of thousands of edges, hash collisions possible): same delays too."""
    sectors, flights, entries = swiss_tables
    r = train(build_problem(entries, sectors, flights, 0.95, 60), "HCMARL", seed=0, episodes=15, readout="best_episode")
    d = r.delay_min
    assert (int(d.sum()), int((d * np.arange(1, d.size + 1)).sum()), r.source) == (1871, 1120341, "best_episode")
