"""The numba kernels of the learners' step (issue 5: MIRL's compiled episode; CMARL's and HCMARL's) give what the step
made of separate calls gives, bit for bit; the per-flight baseline (tests/dcb/test_learners.py) and the former numpy evaluation
(tests/dcb/test_fast_paths.py) check the same kernels against implementations of their own."""

import numpy as np
import pytest
from numba import njit

from models.dcb.cmarl import CoordinatedQ
from models.dcb.mirl import IndependentQ
from models.dcb.train import ABSTRACT_STEP_MIN, GROUND, Level, run_episode
from models.jit import jit


@njit
def _draws_in_numba(rng, n):
    return rng.random(n), rng.integers(0, 2, n)


def test_numba_draws_are_numpys_draws():
    """MIRL's compiled episode draws with numba's Generator.random / .integers on the episode's generator: the same
    numbers as numpy's calls in the same order and sizes, and the generator left in the same state (odd sizes
    leave half a 64-bit draw buffered in it: the next `integers` must find it)."""
    for seed in range(5):
        here, there = np.random.default_rng(seed), np.random.default_rng(seed)
        for n in np.random.default_rng(seed + 100).integers(0, 300, 50):
            u, coin = _draws_in_numba(there, n)
            assert np.array_equal(u, here.random(n)) and np.array_equal(coin, here.integers(0, 2, n)) and coin.dtype == np.int64
            assert here.bit_generator.state == there.bit_generator.state


class CalledQ(IndependentQ):
    """IndependentQ by any other type: `run_episode` calls its values and update at every step instead of running
    MIRL's compiled episode."""


@pytest.mark.parametrize("level", [GROUND, Level(ABSTRACT_STEP_MIN, ABSTRACT_STEP_MIN), Level(ABSTRACT_STEP_MIN, 1), Level(1, ABSTRACT_STEP_MIN)])
def test_compiled_episode_equals_the_step_by_step_episode(small_case, level):
    """Same delays, hotspots, Q tables and generator state over episodes that explore, learn and roll out greedily."""
    p, n_states = small_case, level.n_states(small_case.max_delay_min)
    compiled, called = IndependentQ(p.n_flights, n_states, lr=0.1), CalledQ(p.n_flights, n_states, lr=0.1)
    rng_compiled, rng_called = np.random.default_rng(3), np.random.default_rng(3)
    for eps, learn in ((0.9, True), (0.7, True), (0.3, True), (0.0, False)):
        d, hot = run_episode(p, compiled, level, eps, rng_compiled, learn=learn)
        d_called, hot_called = run_episode(p, called, level, eps, rng_called, learn=learn)
        assert np.array_equal(d, d_called) and hot == hot_called and isinstance(hot, int)
    assert np.array_equal(compiled.q, called.q) and np.abs(compiled.q).sum() > 0 and d.sum() > 0
    assert rng_compiled.bit_generator.state == rng_called.bit_generator.state


class CalledCoordinatedQ(CoordinatedQ):
    """CoordinatedQ by any other type: `run_episode` calls its values and update at every step."""

    def transferred(self, n_states, state_map):
        return CalledCoordinatedQ(self.n_flights, n_states, prior=self, state_map=state_map, lr=self.lr, gamma=self.gamma)


def test_compiled_coordinated_episode_equals_the_step_by_step_episode(small_case):
    """CMARL's compiled episode, at HCMARL's abstract level and at the ground level transferred from it (two stacked
    tables): same delays, hotspots, hashed tables and generator state as the episode that calls values and update."""
    p, abstract = small_case, Level(ABSTRACT_STEP_MIN, ABSTRACT_STEP_MIN)
    compiled, called = (cls(p.n_flights, abstract.n_states(p.max_delay_min), lr=0.1) for cls in (CoordinatedQ, CalledCoordinatedQ))
    rng_compiled, rng_called = np.random.default_rng(3), np.random.default_rng(3)
    for level in (abstract, GROUND):
        if level is GROUND:
            compiled, called = (q.transferred(GROUND.n_states(p.max_delay_min), abstract.state_map(p.max_delay_min)) for q in (compiled, called))
        for eps, learn in ((0.9, True), (0.7, True), (0.3, True), (0.0, False)):
            d, hot = run_episode(p, compiled, level, eps, rng_compiled, learn=learn)
            d_called, hot_called = run_episode(p, called, level, eps, rng_called, learn=learn)
            assert np.array_equal(d, d_called) and hot == hot_called and isinstance(hot, int)
        assert np.array_equal(compiled._tables, called._tables) and np.count_nonzero(compiled.table) > 0 and d.sum() > 0
    assert rng_compiled.bit_generator.state == rng_called.bit_generator.state


def test_evaluate_refuses_delays_that_leave_the_grid(small_case):
    """The compiled evaluation counts into a fixed array: keys outside it are refused, not written out of bounds."""
    p = small_case
    with pytest.raises(ValueError, match=r"^delays -100000\.\.0 min: outside \[0, MaxDelay 60\] min, the range the learners' evaluation is made for$"):
        p.evaluate(np.r_[-100_000, np.zeros(p.n_flights - 1, dtype=np.int64)])
    with pytest.raises(ValueError, match=r"^delays -100000\.\.0 min: outside the problem's 48-hour grid$"):
        p.evaluate(np.r_[-100_000, np.zeros(p.n_flights - 1, dtype=np.int64)], all_entries=True)
    with pytest.raises(ValueError, match=r"^delays of up to \d+ min run past the problem's 48-hour grid$"):
        p.evaluate(np.full(p.n_flights, 60 * (p.n_hours - 12)), all_entries=True)


def _latest_entry_delays(p, hour: int) -> np.ndarray:
    """Delays that put the day's latest entry at the start of `hour`, every other flight undelayed."""
    e = int(np.argmax(p.entry_whole_min))
    delay = np.zeros(p.n_flights, dtype=np.int64)
    delay[p.entry_flight[e]] = 60 * hour - p.entry_whole_min[e]
    return delay


def test_evaluate_refuses_exactly_the_spare_hour(small_case):
    """With all_entries, the grid's last hour is spare (FCFS and the optimum must stay before it): an entry in it is
    refused, an entry one hour earlier is not."""
    p = small_case
    assert p.evaluate(_latest_entry_delays(p, p.n_hours - 2), all_entries=True).counts.sum() == p.entry_flight.size
    with pytest.raises(ValueError, match="run past the problem's 48-hour grid"):
        p.evaluate(_latest_entry_delays(p, p.n_hours - 1), all_entries=True)


def test_evaluate_refuses_an_entry_pushed_into_another_sectors_hours(small_case):
    """A delay of a whole grid moves an entry's key into the next sector's block at the same hour of the block (not
    the spare hour, not outside the array): refused, not counted as the other sector's. The learners' evaluation
    also refuses a delay past MaxDelay (its entries and the keys' shift are chosen for delays up to it), which
    all_entries counts (FCFS delays are not capped)."""
    p = small_case
    f = next(f for f in np.unique(p.entry_flight[p.relevant]) if (p.entry_sector[p.entry_flight == f] < p.n_sectors - 1).all())
    delay = np.zeros(p.n_flights, dtype=np.int64)
    delay[f] = 60 * p.n_hours
    with pytest.raises(ValueError, match="run past the problem's 48-hour grid"):
        p.evaluate(delay, all_entries=True)
    for d in (p.max_delay_min + 1, -1):  # -1: its keys would stay on the grid, only the delay itself is wrong
        delay[f] = d
        with pytest.raises(ValueError, match=r"outside \[0, MaxDelay 60\] min"):
            p.evaluate(delay)
    with pytest.raises(ValueError, match="outside the problem's 48-hour grid"):
        p.evaluate(delay, all_entries=True)
    delay[f] = p.max_delay_min + 1
    assert p.evaluate(delay, all_entries=True).counts.sum() == p.entry_flight.size
    delay[:], delay[p.entry_flight[p.entry_sector == p.n_sectors - 1][0]] = 0, 60 * p.n_hours  # the last sector: past the array
    with pytest.raises(ValueError, match="outside the problem's 48-hour grid"):
        p.evaluate(delay, all_entries=True)


def test_a_kernel_compiles_where_numba_finds_no_cache_directory():
    """numba refuses to define a cached function it finds no writable cache directory for (a read-only checkout with
    no NUMBA_CACHE_DIR and no writable home); the kernels are then compiled in every process instead."""
    namespace = {}
    exec("def twice(x):\n    return 2 * x\n", namespace)  # no source file: no cache directory for it either
    with pytest.raises(RuntimeError, match="no locator"):
        njit(cache=True)(namespace["twice"])
    assert jit(namespace["twice"])(21) == 42


def test_learners_train_with_the_compiled_episode(small_case, monkeypatch):
    """MIRL, CMARL and their hierarchical variants with the thesis state and reward take the compiled episode at every
    level and in the greedy roll-out; with another reward only the roll-out (no learning) does, with the extended
    state none. Without this nothing fails when the fast path is lost: both paths give the same delays."""
    from models.dcb import train as training

    calls = []
    for name in ("_independent_episode", "_coordinated_episode"):
        compiled = getattr(training, name)
        monkeypatch.setattr(training, name, lambda *args, _c=compiled, _n=name: calls.append(_n) or _c(*args))
    independent, coordinated = "_independent_episode", "_coordinated_episode"
    for method, options, expected in (
        ("sHMIRL", {}, [independent] * 5), ("MIRL", {"reward": "difference"}, [independent]), ("MIRL", {"state": "extended"}, []),
        ("CMARL", {}, [coordinated] * 3), ("HCMARL", {}, [coordinated] * 5), ("CMARL", {"reward": "overload"}, [coordinated]),
    ):
        calls.clear()
        training.train(small_case, method, seed=0, episodes=2, **options)
        assert calls == expected, (method, options)


def test_a_q_table_too_small_for_the_problem_and_level_is_one_line(small_case):
    """The kernels index the Q table without bounds checks: a table of fewer flights or states than the episode reaches
    (a learner made for another problem or level) is refused before it is read or written past its rows."""
    p, n_states = small_case, GROUND.n_states(small_case.max_delay_min)
    for short in (IndependentQ(p.n_flights - 1, n_states), CalledQ(p.n_flights, n_states - 1), CoordinatedQ(p.n_flights + 1, n_states),
                  CoordinatedQ(p.n_flights, n_states - 4)):
        rows, states = short.n_flights, short.n_states
        with pytest.raises(ValueError, match=rf"^Q table of {rows} flights × {states} states: this problem and level need 189 × {n_states}$"):
            run_episode(p, short, GROUND, 0.5, np.random.default_rng(0))
