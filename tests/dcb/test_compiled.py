"""The numba kernels of the learners' step (issue 5: MIRL's compiled episode; CMARL's and HCMARL's) give what the step
made of separate calls gives, bit for bit; the per-flight baseline (tests/dcb/test_learners.py) and the former numpy evaluation
(tests/dcb/test_fast_paths.py) check the same kernels against implementations of their own."""

import numpy as np
import pytest
from numba import njit

from models.dcb import kernels
from models.dcb.cmarl import CoordinatedQ
from models.dcb.mirl import IndependentQ
from models.dcb.train import ABSTRACT_STEP_MIN, GROUND, Level, run_episode


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
    with pytest.raises(ValueError, match=r"^delays -100000\.\.0 min put entries outside the problem's 48-hour grid$"):
        p.evaluate(np.r_[-100_000, np.zeros(p.n_flights - 1, dtype=np.int64)])
    with pytest.raises(ValueError, match=r"^delays of up to \d+ min run past the problem's 48-hour grid$"):
        p.evaluate(np.full(p.n_flights, 60 * (p.n_hours - 12)), all_entries=True)


def test_a_kernel_compiles_where_numba_finds_no_cache_directory():
    """numba refuses to define a cached function it finds no writable cache directory for (a read-only checkout with
    no NUMBA_CACHE_DIR and no writable home); the kernels are then compiled in every process instead."""
    namespace = {}
    exec("def twice(x):\n    return 2 * x\n", namespace)  # no source file: no cache directory for it either
    with pytest.raises(RuntimeError, match="no locator"):
        njit(cache=True)(namespace["twice"])
    assert kernels._jit(namespace["twice"])(21) == 42
