"""MIRL: multi-agent independent Q-learning (thesis §5.4.1), one tabular Q_i per flight-agent.

    Q(s, a) = Σ_i Q_i(s_i, a_i)                                                  (Eq 5.5)
    Q_i(s_i, a_i) <- (1 - η) Q_i(s_i, a_i) + η [ r_i + γ max_a* Q_i(s'_i, a*) ]   (Eq 5.6, local reward)

The action values and the update of all agents that act in a step are each one numba kernel (models/dcb/kernels.py;
numpy's fancy indexing was ~10 calls per step, mostly per-call overhead); `update_loop` is the same update one
flight at a time in Python, kept as the benchmark's baseline.
"""

import numpy as np

from models.dcb import kernels

LEARNING_RATE = 0.01  # η, thesis §5.6.2
GAMMA = 0.99  # γ, thesis §5.6.2


class IndependentQ:
    """Q[flight, state, action] for all flights; action 0 = hold, 1 = add one delay step."""

    def __init__(self, n_flights: int, n_states: int, prior: np.ndarray | None = None, lr: float = LEARNING_RATE, gamma: float = GAMMA):
        self.q = np.zeros((n_flights, n_states, 2)) if prior is None else prior.copy()
        self.lr, self.gamma = lr, gamma

    @property
    def n_flights(self) -> int:
        return self.q.shape[0]

    @property
    def n_states(self) -> int:
        return self.q.shape[1]

    def values(self, state: np.ndarray, agents: np.ndarray, ev) -> np.ndarray:
        """Q_i(s_i, ·) of the acting agents -> [agents, 2]."""
        return kernels.q_values(self.q, state, agents)

    def update(self, state, action, reward, next_state, agents) -> None:
        kernels.q_update(self.q, state, action, reward, next_state, agents, self.lr, self.gamma)

    def update_loop(self, state, action, reward, next_state, agents) -> None:
        """The same update as `update`, one flight at a time (benchmark baseline only)."""
        for i in agents:
            s, s2, a = state[i], next_state[i], action[i]
            target = reward[i] + self.gamma * max(self.q[i, s2, 0], self.q[i, s2, 1])
            self.q[i, s, a] += self.lr * (target - self.q[i, s, a])

    def transferred(self, n_states: int, state_map: np.ndarray) -> "IndependentQ":
        """Ground-level learner initialised from this (abstract) one: Q_ground(s) = Q_abstract(φ(s))."""
        return IndependentQ(self.q.shape[0], n_states, prior=self.q[:, state_map], lr=self.lr, gamma=self.gamma)
