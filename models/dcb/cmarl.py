"""CMARL: collaborative Q-learning on the coordination graph (thesis §5.4.2), and its hierarchical
transfer used by HCMARL (§5.5.2).

Peers are flights that share a hotspot; the graph is rebuilt every step because delays move demand.
Every edge (i, j) has a joint Q-function over the joint state s_ij = (s_i, s_j) and joint action:

    Q_ij(s_ij, a_ij) <- (1 - η) Q_ij + η [ r_i/|N(A_i)| + r_j/|N(A_j)| + γ Q_ij(s'_ij, a*_ij) ]   (Eq 5.7, 5.12)
    Q_i(s_i, a_i)  = ½ Σ_{j ∈ N(A_i)} max_{a_j} Q_ij(s_ij, (a_i, a_j))                          (Eq 5.9)
    a*_i = argmax_{a_i} Q_i(s_i, a_i)                                                            (Eq 5.8)

a*_ij in the target is the best joint action of the edge's own table at s'_ij (the next step's graph
is not known yet when the edge is updated).

Storage: the joint tables Q_ij are tabular but sparse (a day has thousands of possible peer pairs
and (states)^2 x 4 entries each), so they live in one [2^20, 4] array whose row is a multiplicative
hash of (i, j, s_i, s_j) and whose 4 columns are the joint actions (one cache line per edge lookup).
Two keys can share a row (2^20 rows; the visited joint states are a few hundred thousand at most, so
collisions are rare) - the same approximation as CMAC hashing in Sutton & Barto §9.5.4.
HCMARL's transfer: a ground lookup is Q_abstract(φ(s_ij)) + ΔQ_ground(s_ij), with ΔQ starting at 0 -
exactly "copy the abstract Q-values down", done lazily for the keys actually visited.
"""

import numpy as np

from models.dcb.mirl import GAMMA, LEARNING_RATE, row_max

TABLE_BITS = 20
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)


def peer_edges(ev, flight_of_entry: np.ndarray, n_flights: int) -> tuple[np.ndarray, np.ndarray]:
    """Coordination graph: unique pairs (i < j) of flights with an entry in the same hotspot."""
    hot = np.nonzero(ev.entry_hot)[0]
    order = np.argsort(ev.entry_key[hot], kind="stable")
    key, flight = ev.entry_key[hot][order], flight_of_entry[hot][order]
    group_end = np.searchsorted(key, key, side="right")  # every entry pairs with the later ones of its group
    later = group_end - np.arange(key.size) - 1
    first = np.repeat(np.arange(key.size), later)
    second = first + 1 + np.arange(first.size) - np.repeat(np.cumsum(later) - later, later)
    i, j = np.minimum(flight[first], flight[second]), np.maximum(flight[first], flight[second])
    pair = np.sort(i[i != j] * n_flights + j[i != j])
    first_of_run = np.ones(pair.size, dtype=bool)
    first_of_run[1:] = pair[1:] != pair[:-1]
    pair = pair[first_of_run]  # unique pairs, as np.unique but several times faster here
    return pair // n_flights, pair % n_flights


class CoordinatedQ:
    def __init__(self, n_flights: int, n_states: int, flight_of_entry: np.ndarray, prior: "CoordinatedQ | None" = None,
                 state_map: np.ndarray | None = None, lr: float = LEARNING_RATE, gamma: float = GAMMA):
        self.n_flights, self.n_states, self.flight_of_entry = n_flights, n_states, flight_of_entry
        self.table = np.zeros((1 << TABLE_BITS, 4), dtype=np.float32)
        self.prior, self.state_map = prior, state_map
        self.lr, self.gamma = lr, gamma

    def _rows(self, i, j, s_i, s_j) -> np.ndarray:
        key = ((i * self.n_flights + j) * self.n_states + s_i) * self.n_states + s_j
        return ((key.astype(np.uint64) * _GOLDEN) >> np.uint64(64 - TABLE_BITS)).view(np.int64)  # row < 2^20: same value as int64

    def edge_q(self, i, j, s_i, s_j, rows: np.ndarray | None = None) -> np.ndarray:
        """Q_ij(s_ij, ·) for every edge -> [edges, 4], joint action a_ij = 2·a_i + a_j (`rows`: this table's rows if known)."""
        q = np.take(self.table, self._rows(i, j, s_i, s_j) if rows is None else rows, axis=0).astype(np.float64)  # take: ~10x faster than table[rows]
        if self.prior is not None:
            q += self.prior.edge_q(i, j, self.state_map[s_i], self.state_map[s_j])
        return q

    def values(self, state: np.ndarray, agents: np.ndarray, ev) -> np.ndarray:
        """Q_i(s_i, ·) of the acting agents from their edges (Eq 5.9) -> [agents, 2]."""
        i, j = peer_edges(ev, self.flight_of_entry, self.n_flights)
        rows = self._rows(i, j, state[i], state[j])
        q_flat = self.edge_q(i, j, state[i], state[j], rows)
        self._edges = (i, j, rows, q_flat)  # the update's edges and current Q_ij(s_ij, ·)
        q = q_flat.reshape(-1, 2, 2)  # [edge, a_i, a_j]
        per_flight = np.zeros((self.n_flights, 2))
        for a in (0, 1):
            per_flight[:, a] = 0.5 * (
                np.bincount(i, weights=row_max(q[:, a, :]), minlength=self.n_flights)
                + np.bincount(j, weights=row_max(q[:, :, a]), minlength=self.n_flights)
            )
        return per_flight[agents]

    def update(self, state, action, reward, next_state, agents) -> None:
        """Eq 5.7 on every edge of the graph the actions were chosen on."""
        i, j, rows, q = self._edges
        if i.size == 0:
            return
        degree = np.bincount(np.concatenate([i, j]), minlength=self.n_flights)
        joint = 2 * action[i] + action[j]
        target = reward[i] / degree[i] + reward[j] / degree[j] + self.gamma * row_max(self.edge_q(i, j, next_state[i], next_state[j]))
        current = q[np.arange(i.size), joint]
        # add.at, not +=: two edges may share a hashed row
        np.add.at(self.table.reshape(-1), rows * 4 + joint, (self.lr * (target - current)).astype(np.float32))

    def transferred(self, n_states: int, state_map: np.ndarray) -> "CoordinatedQ":
        """Ground-level learner whose Q starts at this (abstract) learner's Q(φ(s))."""
        return CoordinatedQ(self.n_flights, n_states, self.flight_of_entry, prior=self, state_map=state_map, lr=self.lr, gamma=self.gamma)
