"""A training episode computed one flight at a time: the per-flight baseline that `make bench` times the
vectorised `train.run_episode` against (tests/bench/test_bench_dcb.py). Not used in training.

It is what a non-vectorised implementation of the episode step does (docs/dcb.md, "Benchmarks"): the
sector-hour entry counts are kept up to date entry by entry as flights delay, and at every step, in Python
loops over the flights, each flight in a hotspot chooses its action ε-greedily and moves its entries, then
every flight observes its local state (d_i, h_i) and its congested minutes TDC_i from the counts of its own
entries, and each acting flight gets its reward (Eq 5.2-5.4) and is updated by the learner (a per-flight or
per-edge learner: `PerFlightQ` here, the bench's per-edge CMARL). The random numbers are drawn per step as
`run_episode` draws them (one array per step), so with the same learner both return the same delays and Q
tables (tests/dcb/test_learners.py). Only the thesis reward is implemented: the bench times the default.
"""

from dataclasses import dataclass

import numpy as np

from models.dcb.mirl import IndependentQ
from models.dcb.problem import AVG_DELAY_COST_EUR_PER_MIN, C_PLUS, DCBProblem
from models.dcb.train import H_CAP, Level


class PerFlightQ(IndependentQ):
    """MIRL with the action values and Eq 5.6 computed one flight at a time."""

    def values(self, state, agents, ev):
        return np.array([[self.q[i, state[i], 0], self.q[i, state[i], 1]] for i in agents]).reshape(-1, 2)

    update = IndependentQ.update_loop


@dataclass
class HotEntries:
    """The hot entries a coordinated learner builds its peer graph from (as `Evaluation.hot_key` / `hot_flight`)."""

    hot_key: np.ndarray
    hot_flight: np.ndarray


class PerFlightEpisodes:
    """The problem's relevant entries regrouped per flight as Python lists, once (outside the timed episodes)."""

    def __init__(self, problem: DCBProblem):
        e = problem.relevant_entries
        self.problem = problem
        self.own = [[] for _ in range(problem.n_flights)]  # per flight: (key_base, whole minute, duration) in entry order
        for base, m, dur, f in zip(e.key_base.tolist(), e.whole_min.tolist(), e.dur_min.tolist(), e.flight.tolist()):
            self.own[f].append((base, m, dur))
        self.active = [f for f in range(problem.n_flights) if self.own[f]]  # flights with no such entry never act
        self.capacity = problem.capacity.tolist()
        self.delay_cost = problem.delay_cost.tolist()  # λ · DC_i per minute of delay

    def run_episode(self, learner, level: Level, eps: float, rng: np.random.Generator, learn: bool = True) -> tuple[np.ndarray, int]:
        """One episode from zero delays, as `train.run_episode` with the thesis reward -> (delays [min], hotspots left)."""
        if level.n_extra != 1:  # the bench times the defaults; silently differing from run_episode would be worse
            raise ValueError("the per-flight baseline implements the thesis's local state (d_i, h_i) only")
        p, own, cap, step = self.problem, self.own, self.capacity, level.action_step
        delay = [0] * p.n_flights
        counts = [0] * len(cap)
        for f in self.active:
            for base, m, _ in own[f]:
                counts[base + m // 60] += 1
        state, hot, tdc, view = self._observe(level, delay, counts, [0] * p.n_flights)
        for _ in range(p.max_delay_min // step):
            # as run_episode: no MaxDelay test, at step t every delay is <= t · step, so one more step stays within it
            agents = [f for f in self.active if hot[f] > 0]
            if not agents:
                break
            q = learner.values(state, agents, view)
            explore, coin = rng.random(len(agents)) < eps, rng.integers(0, 2, len(agents))  # as run_episode draws them
            action = [0] * p.n_flights
            for k, f in enumerate(agents):
                if (coin[k] if explore[k] else q[k, 1] > q[k, 0]):  # ties hold
                    action[f] = 1
                    d = delay[f]
                    for base, m, _ in own[f]:
                        counts[base + (m + d) // 60] -= 1
                        counts[base + (m + d + step) // 60] += 1
                    delay[f] = d + step
            next_state, hot, tdc, view = self._observe(level, delay, counts, state)
            if learn:
                reward = [0.0] * p.n_flights
                for f in agents:  # Eq 5.2-5.4
                    congestion = -AVG_DELAY_COST_EUR_PER_MIN * tdc[f] if tdc[f] > 0 else C_PLUS
                    reward[f] = congestion - self.delay_cost[f] * delay[f]
                learner.update(state, action, reward, next_state, agents)
            state = next_state
        return np.array(delay, dtype=np.int64), sum(c > k for c, k in zip(counts, cap))

    def _observe(self, level: Level, delay, counts, state):
        """Every flight's h_i, TDC_i and local state from the counts of its own entries (+ the hot entries)."""
        own, cap = self.own, self.capacity
        hot, tdc, state = [0] * len(delay), [0.0] * len(delay), list(state)
        hot_key, hot_flight = [], []
        for f in self.active:
            d, h, minutes = delay[f], 0, 0.0
            for base, m, dur in own[f]:
                k = base + (m + d) // 60
                if counts[k] > cap[k]:
                    h, minutes = h + 1, minutes + dur
                    hot_key.append(k)
                    hot_flight.append(f)
            hot[f], tdc[f] = h, minutes
            state[f] = (d // level.state_step) * (H_CAP + 1) + min(h, H_CAP)
        return state, hot, tdc, HotEntries(np.array(hot_key, dtype=np.int64), np.array(hot_flight, dtype=np.int64))
