"""Hotspot counting on a hand-built case, and the integer program against brute force."""

import itertools
import subprocess
import sys
from datetime import datetime, timedelta, timezone

import numpy as np
import polars as pl
import pytest

from models.dcb.optimum import fcfs, solve_optimum
from models.dcb.problem import REGULATED_MIN, DCBProblem, hotspot_table

T0 = datetime(2018, 8, 1, tzinfo=timezone.utc)


def make_problem(rows, capacity, max_delay_min=60):
    """rows: (flight, sector, entry minute, minutes inside)."""
    entries = pl.DataFrame({
        "flight_id": [r[0] for r in rows], "sector": [r[1] for r in rows],
        "entry_ts": [T0 + timedelta(minutes=r[2]) for r in rows], "exit_ts": [T0 + timedelta(minutes=r[2] + r[3]) for r in rows],
    }).with_columns(pl.col("entry_ts", "exit_ts").cast(pl.Datetime("us", "UTC")))
    flights = pl.DataFrame({"flight_id": sorted({r[0] for r in rows}), "aircraft_class": "unknown"})
    return DCBProblem(entries, capacity, flights, max_delay_min)


def test_hotspots_of_a_hand_built_case():
    # sector A (capacity 2): 3 entries in 10:00-11:00 -> hotspot; 2 entries in 11:00-12:00 -> at capacity, no hotspot
    # sector B (capacity 1): f1 and f4 enter in 10:00-11:00 -> hotspot; f5 alone at 12:30 -> none
    rows = [("f1", "A", 600, 10), ("f2", "A", 610, 5), ("f3", "A", 659, 20), ("f4", "A", 660, 7), ("f5", "A", 700, 3),
            ("f1", "B", 615, 12), ("f4", "B", 640, 4), ("f5", "B", 750, 6)]
    p = make_problem(rows, {"A": 2, "B": 1})
    zero = np.zeros(p.n_flights, dtype=np.int64)
    ev = p.evaluate(zero, all_entries=True)
    assert ev.hotspots == 2
    assert dict(zip(p.flight_ids, ev.hotspots_per_flight)) == {"f1": 2, "f2": 1, "f3": 1, "f4": 1, "f5": 0}
    assert dict(zip(p.flight_ids, ev.congested_min)) == {"f1": 22.0, "f2": 5.0, "f3": 20.0, "f4": 4.0, "f5": 0.0}
    # the learners' reduced evaluation sees the same hotspots and the same per-flight picture
    small = p.evaluate(zero)
    assert small.hotspots == 2 and (small.hotspots_per_flight == ev.hotspots_per_flight).all()
    table = hotspot_table(p, zero).filter("is_hotspot").sort("sector")
    assert table.select("sector", "demand", "capacity").rows() == [("A", 3, 2), ("B", 2, 1)]
    assert table["hour"].to_list() == [T0 + timedelta(hours=10)] * 2
    # delaying f3 by 1 min moves its entry to 11:00 -> A 10:00 has 2 (ok) but A 11:00 gets 3 -> still 2 hotspots
    d = zero.copy()
    d[p.flight_ids.index("f3")] = 1
    assert p.evaluate(d, all_entries=True).hotspots == 2
    # delaying f4 by 20 min (B entry at 11:00) and f3 by 61 min (A entry at 12:00) resolves both
    d[p.flight_ids.index("f4")], d[p.flight_ids.index("f3")] = 20, 61
    assert p.evaluate(d, all_entries=True).hotspots == 0


def brute_force(p: DCBProblem) -> tuple[int, int]:
    """(least total delay, fewest regulated flights among the schedules with that delay)."""
    best = None
    for combo in itertools.product(range(p.max_delay_min + 1), repeat=p.n_flights):
        d = np.array(combo)
        if p.evaluate(d, all_entries=True).hotspots == 0 and (best is None or (d.sum(), (d >= REGULATED_MIN).sum()) < best):
            best = (int(d.sum()), int((d >= REGULATED_MIN).sum()))
    return best


@pytest.mark.parametrize("capacity", [{"A": 2, "B": 1}, {"A": 2, "B": 2}])
def test_integer_program_matches_brute_force(capacity):
    # entries close to the hour boundary so that small delays (<= 6 min) can move them on
    rows = [("f1", "A", 55, 5), ("f2", "A", 56, 5), ("f3", "A", 57, 5), ("f4", "A", 114, 5),
            ("f1", "B", 58, 5), ("f4", "B", 59, 5), ("f2", "B", 118, 5)]
    p = make_problem(rows, capacity, max_delay_min=6)
    delay, _ = solve_optimum(p)
    assert p.evaluate(delay, all_entries=True).hotspots == 0
    assert (int(delay.sum()), int((delay >= REGULATED_MIN).sum())) == brute_force(p) and delay.sum() > 0
    first_come = fcfs(p)  # FCFS resolves every hotspot too, never with less delay than the optimum
    assert p.evaluate(first_come, all_entries=True).hotspots == 0 and first_come.sum() >= delay.sum()


def test_among_equally_short_schedules_the_optimum_regulates_fewest():
    # 4 min in all either way: f1 +4 (one regulated flight) or f2 +2 out of A's full hour, which pushes its B entry
    # into f3's hour, and f3 +2 on (no regulated flight)
    rows = [("f1", "A", 56, 5), ("f2", "A", 58, 5), ("f2", "B", 119, 5), ("f3", "B", 178, 5)]
    p = make_problem(rows, {"A": 1, "B": 1}, max_delay_min=6)
    delay, _ = solve_optimum(p)
    assert brute_force(p) == (4, 0)
    assert delay.tolist() == [0, 2, 2]


def test_the_tie_break_never_buys_a_minute_of_delay():
    # 8 min with two regulated flights (h1, h2 +4) against 9 min with none (s +3, pushing t1 and t2 on): a weight of the
    # second term not below one minute would pick the 9 minutes
    rows = [("h1", "A", 56, 5), ("s", "A", 57, 5), ("s", "C", 117, 5), ("h2", "C", 116, 5), ("s", "D", 178, 5),
            ("t1", "D", 237, 5), ("t1", "E", 297, 5), ("t2", "E", 357, 5)]
    p = make_problem(rows, {"A": 1, "C": 1, "D": 1, "E": 1}, max_delay_min=6)
    delay, _ = solve_optimum(p)
    assert brute_force(p) == (8, 2)
    assert dict(zip(p.flight_ids, delay.tolist())) == {"h1": 4, "h2": 4, "s": 0, "t1": 0, "t2": 0}


def test_optimum_reports_infeasible_within_max_delay():
    from models.dcb.optimum import InfeasibleError

    p = make_problem([("f1", "A", 0, 5), ("f2", "A", 1, 5)], {"A": 1}, max_delay_min=10)
    with pytest.raises(InfeasibleError, match="Infeasible"):
        solve_optimum(p)


def test_fcfs_that_would_run_past_the_hour_grid_is_infeasible():
    from models.dcb.optimum import InfeasibleError

    # 60 flights in one sector-hour at capacity 1: FCFS would push the last one 59 hours on, past the 48-hour grid
    p = make_problem([(f"f{i:02d}", "A", 600 + i % 60, 5) for i in range(60)], {"A": 1})
    with pytest.raises(InfeasibleError, match=r"FCFS needs delays of up to \d+ min, past the problem's 48-hour grid") as e:
        fcfs(p)
    assert "\n" not in str(e.value)


HAND_BUILT = [("f1", "A", 600, 10), ("f2", "A", 610, 5), ("f3", "A", 659, 20), ("f4", "A", 660, 7), ("f5", "A", 700, 3),
              ("f1", "B", 615, 12), ("f4", "B", 640, 4), ("f5", "B", 750, 6)]


def test_movers_are_the_entries_closest_to_the_end_of_their_hour():
    # A 10:00 (capacity 2): f1, f2, f3 enter at :00, :10, :59 -> excess 1, f3 leaves the hour first;
    # B 10:00 (capacity 1): f1 at :15, f4 at :40 -> excess 1, f4 leaves first
    p = make_problem(HAND_BUILT, {"A": 2, "B": 1})
    zero = np.zeros(p.n_flights, dtype=np.int64)
    assert dict(zip(p.flight_ids, p.movers(zero, p.evaluate(zero)))) == {"f1": 0, "f2": 0, "f3": 1, "f4": 1, "f5": 0}


def assert_is_own_change_of(p, reward, total):
    """reward(added, before, after)[i] == total(after) - total(after with i's action undone), 40 random steps of 1 or 10 min."""
    rng = np.random.default_rng(0)
    for _ in range(40):
        before = rng.integers(0, 50, p.n_flights)
        added = rng.integers(0, 2, p.n_flights) * rng.choice([1, 10])
        after = before + added
        r = reward(added, p.evaluate(before), p.evaluate(after))
        for i in range(p.n_flights):
            undone = after.copy()
            undone[i] = before[i]
            assert r[i] == pytest.approx(total(after) - total(undone))


def test_difference_reward_is_each_flights_own_change_of_the_day_total():
    """D_i = G(z) - G(z with i's action undone), G = -81 Σ TDC - λ Σ DC, checked against recomputing G."""
    p = make_problem(HAND_BUILT, {"A": 2, "B": 1})

    def total(d):
        return -81.0 * p.evaluate(d, all_entries=True).congested_min.sum() - 20.0 * (p.delay_weight * d).sum()

    assert_is_own_change_of(p, p.difference_reward, total)
    # f3 delayed 1 min clears A 10:00 (15 + 20 congested min gone) and overloads A 11:00 (f3, f4, f5: 30 min): 81 * 5 - 20
    zero = np.zeros(p.n_flights, dtype=np.int64)
    one = (np.array(p.flight_ids) == "f3").astype(np.int64)
    assert p.difference_reward(one, p.evaluate(zero), p.evaluate(one)).tolist() == [0.0, 0.0, 385.0, 0.0, 0.0]


def test_the_solver_prints_nothing():
    """HiGHS writes its banner to the process's C stdout (once per process, so a fresh one), where no Python redirect
    catches it: it landed between the DCB run's progress lines."""
    solve = "from tests.dcb.test_problem import make_problem; from models.dcb.optimum import solve_optimum; " \
            "print(solve_optimum(make_problem([('f1', 'A', 55, 5), ('f2', 'A', 56, 5)], {'A': 1}, 6))[0].tolist())"
    out = subprocess.run([sys.executable, "-c", solve], capture_output=True, text=True, check=True).stdout
    assert out == "[0, 4]\n"  # f2 (entering at 00:56) moved into the next hour: the result and nothing else
