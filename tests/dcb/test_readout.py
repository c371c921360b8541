"""The read-out (repair + trim) and the overload reward: hand-built cases with known answers, the small real case."""

import numpy as np
import pytest

from models.dcb.optimum import solve_optimum
from models.dcb.readout import polish, readout_only, repair, trim
from models.dcb.train import train
from tests.dcb.test_problem import HAND_BUILT, assert_is_own_change_of, make_problem


def delays(p, **by_flight):
    d = np.zeros(p.n_flights, dtype=np.int64)
    for f, v in by_flight.items():
        d[p.flight_ids.index(f)] = v
    return d


def test_repair_of_the_hand_built_case():
    """A 10:00 (capacity 2): f1 :00, f2 :10, f3 :59 -> f3, the last come, is pushed 1 min into 11:00; B 10:00 (capacity 1):
    f1 :15, f4 :40 -> f4 pushed 20 min; A 11:00 then holds f3, f4, f5 (:40) -> f5 pushed 20 min, the cascade resolved.
    That is the optimum here (41 min)."""
    p = make_problem(HAND_BUILT, {"A": 2, "B": 1})
    fixed = repair(p, np.zeros(p.n_flights, dtype=np.int64))
    assert fixed.tolist() == delays(p, f3=1, f4=20, f5=20).tolist()
    assert p.evaluate(fixed, all_entries=True).hotspots == 0
    assert fixed.sum() == solve_optimum(p)[0].sum() == 41 == readout_only(p).sum()


def test_trim_removes_the_delay_no_hotspot_needs():
    """f1 and f2 need no delay once f3 has left A 10:00 and f4 B 10:00; f4 needs 20 min, not 35 (B entry at :40)."""
    p = make_problem(HAND_BUILT, {"A": 2, "B": 1})
    trimmed = trim(p, delays(p, f1=30, f2=5, f3=1, f4=35, f5=20))
    assert trimmed.tolist() == delays(p, f3=1, f4=20, f5=20).tolist()


def test_repair_stays_within_max_delay_and_leaves_what_it_cannot_resolve():
    p = make_problem([("f1", "A", 0, 5), ("f2", "A", 1, 5)], {"A": 1}, max_delay_min=10)  # leaving the hour needs 59 min
    zero = np.zeros(p.n_flights, dtype=np.int64)
    assert repair(p, zero).tolist() == [0, 0] and polish(p, zero).tolist() == [0, 0]
    assert p.evaluate(polish(p, zero), all_entries=True).hotspots == 1


def test_polish_on_the_small_real_case(small_case):
    """Random schedules: no hotspot left, delays only within [0, MaxDelay], never below the optimum (20 min), trim is a fixed point."""
    p = small_case
    rng = np.random.default_rng(0)
    for _ in range(10):
        start = rng.integers(0, 30, p.n_flights) * (rng.random(p.n_flights) < 0.3)
        out = polish(p, start)
        assert p.evaluate(out, all_entries=True).hotspots == 0
        assert 0 <= out.min() and out.max() <= p.max_delay_min and out.sum() >= 20
        assert np.array_equal(trim(p, out), out)


def test_overload_reward_is_each_flights_own_change_of_the_day_overload():
    """D_i = G(z) - G(z with i's action undone), G = -P Σ_k max(0, count_k - capacity_k) - λ Σ DC, P = 2 λ MaxDelay."""
    p = make_problem(HAND_BUILT, {"A": 2, "B": 1})
    penalty = 2 * 20.0 * p.max_delay_min

    def total(d):
        ev = p.evaluate(d, all_entries=True)
        return -penalty * np.maximum(ev.counts - p.capacity, 0).sum() - 20.0 * (p.delay_weight * d).sum()

    assert_is_own_change_of(p, p.overload_reward, total)
    zero = np.zeros(p.n_flights, dtype=np.int64)
    # f3 + 1 min only moves the overload from A 10:00 to A 11:00: its delay cost, nothing more
    one = delays(p, f3=1)
    assert p.overload_reward(one, p.evaluate(zero), p.evaluate(one)).tolist() == [0.0, 0.0, -20.0, 0.0, 0.0]
    # f4 + 20 min clears B 10:00 and lands in an hour with room: P - 20 * 20
    f4 = delays(p, f4=20)
    assert p.overload_reward(f4, p.evaluate(zero), p.evaluate(f4)).tolist() == [0.0, 0.0, 0.0, 2000.0, 0.0]


@pytest.mark.parametrize("method", ["MIRL", "HCMARL"])
def test_repair_readout_against_the_raw_candidates(small_case, method):
    """Same training (same seed), two read-outs: the repaired one leaves no hotspot and never more delay."""
    raw = train(small_case, method, seed=0, episodes=20, readout="best_episode")
    fixed = train(small_case, method, seed=0, episodes=20)
    assert (raw.greedy_hotspots, raw.greedy_delay_min) == (fixed.greedy_hotspots, fixed.greedy_delay_min)
    assert fixed.hotspots_left == 0 == small_case.evaluate(fixed.delay_min, all_entries=True).hotspots
    assert fixed.delay_min.sum() <= raw.delay_min.sum()
    with pytest.raises(ValueError, match="unknown DCB read-out 'last'"):
        train(small_case, "MIRL", seed=0, episodes=1, readout="last")


def test_overload_reward_policy(small_case):
    """MIRL, seed 0, 40 episodes, η = 0.1: the overload reward's greedy policy itself resolves the small case with the
    optimum's 20 min; the thesis reward's greedy policy resolves it too, but with 154 min (lockstep over-delay)."""
    thesis = train(small_case, "MIRL", seed=0, episodes=40, learning_rate=0.1)
    r = train(small_case, "MIRL", seed=0, episodes=40, reward="overload", learning_rate=0.1)
    assert r.greedy_hotspots == 0 and r.greedy_delay_min <= 1.2 * 20
    assert thesis.greedy_delay_min > 5 * r.greedy_delay_min


def test_polish_never_returns_more_hotspots_than_it_was_given():
    """Repairing S1 10:00 FCFS pushes A (the last come) 10 min, which drops its S2/S3 entries into hours held by C and D
    (they cannot leave: 40 min already): repair alone ends with 2 hotspots. polish keeps the input (1 hotspot) instead."""
    rows = [
        ("A", "S1", 650, 5), ("A", "S2", 655, 5), ("A", "S3", 658, 5), ("B", "S1", 610, 5),
        ("C", "S2", 650, 5), ("C", "S4", 650, 5), ("E", "S4", 605, 5),
        ("D", "S3", 650, 5), ("D", "S5", 650, 5), ("G", "S5", 605, 5),
    ]
    p = make_problem(rows, {s: 1 for s in ["S1", "S2", "S3", "S4", "S5"]})
    given = delays(p, C=40, D=40)
    hot = lambda d: p.evaluate(d, all_entries=True).hotspots  # noqa: E731
    assert hot(given) == 1 and hot(repair(p, given)) == 2
    assert hot(polish(p, given)) == 1


def test_read_out_refuses_delays_outside_zero_to_max_delay():
    p = make_problem(HAND_BUILT, {"A": 2, "B": 1})
    with pytest.raises(ValueError, match="delays must lie in"):
        repair(p, np.full(p.n_flights, p.max_delay_min + 1))
