"""MIRL: multi-agent independent Q-learning (thesis §5.4.1), one tabular Q_i per flight-agent.

    Q(s, a) = Σ_i Q_i(s_i, a_i)                                                  (Eq 5.5)
    Q_i(s_i, a_i) <- (1 - η) Q_i(s_i, a_i) + η [ r_i + γ max_a* Q_i(s'_i, a*) ]   (Eq 5.6, local reward)

All agents that act in a step are updated at once with fancy indexing (no per-flight loop);
`update_loop` is the same update one flight at a time, kept as the benchmark's baseline.
"""

import numpy as np

LEARNING_RATE = 0.01  # η, thesis §5.6.2
GAMMA = 0.99  # γ, thesis §5.6.2


class IndependentQ:
    """Q[flight, state, action] for all flights; action 0 = hold, 1 = add one delay step."""

    def __init__(self, n_flights: int, n_states: int, prior: np.ndarray | None = None, lr: float = LEARNING_RATE, gamma: float = GAMMA):
        self.q = np.zeros((n_flights, n_states, 2)) if prior is None else prior.copy()
        self.lr, self.gamma = lr, gamma
        # flat views of the C-contiguous table (copy=False: raise rather than update a copy): row i·S + s holds Q_i(s, ·),
        # cell 2·row + a holds Q_i(s, a); `take` on rows is ~2x faster than q[agents, s], 1-d cells ~3x faster than triples
        self._rows = self.q.reshape(-1, 2, copy=False)
        self._cells = self._rows.reshape(-1, copy=False)
        self._now = None  # (state, agents, their rows) of the last `values`, which `update` reuses

    def _row(self, agents: np.ndarray, s: np.ndarray) -> np.ndarray:
        return agents * self.q.shape[1] + s

    def values(self, state: np.ndarray, agents: np.ndarray, ev) -> np.ndarray:
        """Q_i(s_i, ·) of the acting agents -> [agents, 2]. `update` with the same `state` and `agents` arrays
        (as `run_episode` passes them) reuses their rows: callers must not modify them in place in between."""
        row = self._row(agents, state[agents])
        self._now = (state, agents, row)
        return self._rows.take(row, axis=0)

    def update(self, state, action, reward, next_state, agents) -> None:
        state_now, agents_now, row = self._now or (None, None, None)
        if state is not state_now or agents is not agents_now:
            row = self._row(agents, state[agents])
        cell = 2 * row + action[agents]  # Q_i(s_i, a_i)
        nxt = self._rows.take(self._row(agents, next_state[agents]), axis=0)
        target = reward[agents] + self.gamma * np.maximum(nxt[:, 0], nxt[:, 1])  # Eq 5.6
        old = self._cells[cell]
        self._cells[cell] = old + self.lr * (target - old)

    def update_loop(self, state, action, reward, next_state, agents) -> None:
        """The same update as `update`, one flight at a time (benchmark baseline only)."""
        for i in agents:
            s, s2, a = state[i], next_state[i], action[i]
            target = reward[i] + self.gamma * max(self.q[i, s2, 0], self.q[i, s2, 1])
            self.q[i, s, a] += self.lr * (target - self.q[i, s, a])

    def transferred(self, n_states: int, state_map: np.ndarray) -> "IndependentQ":
        """Ground-level learner initialised from this (abstract) one: Q_ground(s) = Q_abstract(φ(s))."""
        return IndependentQ(self.q.shape[0], n_states, prior=self.q[:, state_map], lr=self.lr, gamma=self.gamma)
