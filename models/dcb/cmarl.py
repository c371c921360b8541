"""CMARL: collaborative Q-learning on the coordination graph (thesis §5.4.2), and its hierarchical
transfer used by HCMARL (§5.5.2).

Peers are flights that share a hotspot; the graph is rebuilt whenever delays move a hot entry.
Every edge (i, j) has a joint Q-function over the joint state s_ij = (s_i, s_j) and joint action:

    Q_ij(s_ij, a_ij) <- (1 - η) Q_ij + η [ r_i/|N(A_i)| + r_j/|N(A_j)| + γ Q_ij(s'_ij, a*_ij) ]   (Eq 5.7, 5.12)
    Q_i(s_i, a_i)  = ½ Σ_{j ∈ N(A_i)} max_{a_j} Q_ij(s_ij, (a_i, a_j))                          (Eq 5.9)
    a*_i = argmax_{a_i} Q_i(s_i, a_i)                                                            (Eq 5.8)

a*_ij in the target is the best joint action of the edge's own table at s'_ij (the next step's graph
is not known yet when the edge is updated).

Storage: the joint tables Q_ij are tabular but sparse (a day has thousands of possible peer pairs
and (states)^2 x 4 entries each), so they live in one [2^20, 4] array whose row is a multiplicative
hash of the key ((i·n + j)·S + s_i)·S + s_j and whose 4 columns are the joint actions (one cache line
per edge lookup). Two keys can share a row (2^20 rows; the visited joint states are a few hundred
thousand at most, so collisions are rare) - the same approximation as CMAC hashing in Sutton & Barto §9.5.4.
HCMARL's transfer: a ground lookup is Q_abstract(φ(s_ij)) + ΔQ_ground(s_ij), with ΔQ starting at 0 -
exactly "copy the abstract Q-values down", done lazily for the keys actually visited.

Speed (a ground step has ~100 hot entries and ~1,000 edges, so the cost is the number of numpy calls,
not the data; the results are bit for bit those of the straightforward version, tests/dcb/test_fast_paths.py):
the hash is linear mod 2^64, key·G = (i·n + j)·S²·G + s_i·S·G + s_j·G, so the edge part is computed once
per graph and the state parts are small lookup tables; the ground and the frozen abstract table are one
array, read with one `take`; the graph and the arrays derived from it are kept while the hot entries stay
the same (about a third of the steps); the update's lookup of the next state is reused by the next step's
action values when the graph is unchanged (only the ground rows are read again).
"""

from dataclasses import dataclass
from functools import reduce

import numpy as np

from models.dcb.mirl import GAMMA, LEARNING_RATE

TABLE_BITS = 20
_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_SHIFT = np.uint64(64 - TABLE_BITS)


def row_max(q: np.ndarray) -> np.ndarray:
    """max over the (4) joint-action columns of every row: np.maximum column by column, as numpy's
    q.max(axis=1) over so few columns is ~40x slower."""
    return reduce(np.maximum, q.T)


def hot_entry_codes(ev, n_flights: int) -> np.ndarray:
    """hotspot · n + flight of every hot entry: the graph depends on nothing else."""
    return ev.hot_key * n_flights + ev.hot_flight


def peer_edges(ev, n_flights: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Coordination graph: unique pairs (i < j, sorted) of flights with an entry in the same hotspot
    -> (i, j, every flight's degree |N(A_i)|, pair code i·n + j)."""
    code = np.sort(hot_entry_codes(ev, n_flights))  # hot entries by hotspot, then by flight
    key, flight = np.divmod(code, n_flights)
    # every entry pairs with the later ones of its hotspot (a flight before its later peers: i <= j)
    entry = np.arange(code.size)
    later = np.searchsorted(key, key, side="right") - entry - 1
    first = np.repeat(entry, later)
    second = np.arange(first.size) + np.repeat(entry + 1 - np.cumsum(later) + later, later)
    i, j = flight[first], flight[second]
    pair = np.sort((i * n_flights + j)[i != j])  # i == j: a flight entering one hotspot twice
    first_of_run = np.ones(pair.size, dtype=bool)
    first_of_run[1:] = pair[1:] != pair[:-1]
    pair = pair[first_of_run]  # unique pairs, as np.unique but several times faster here
    i, j = np.divmod(pair, n_flights)
    return i, j, np.bincount(np.concatenate([i, j]), minlength=n_flights), pair


@dataclass
class _Graph:
    """One coordination graph and the per-edge arrays derived from it, reused while it stays the same."""

    signature: np.ndarray  # [hot entry] hot_entry_codes
    ij: np.ndarray  # [2E] i then j of every edge
    degree: np.ndarray  # [flight] |N(A_i)|, at least 1 (flights with no edge never divide)
    hash_edge: np.ndarray  # [L·E] uint64, (i·n + j)·S_l²·G for every table level l
    level_row: np.ndarray  # [L·E] first row of level l's table in the stacked tables
    bins: np.ndarray  # [4E] Eq 5.9 sums, bin a·2n + side·n + flight for the edge seen from i (side 0) or j (1)


class CoordinatedQ:
    def __init__(self, n_flights: int, n_states: int, prior: "CoordinatedQ | None" = None, state_map: np.ndarray | None = None,
                 lr: float = LEARNING_RATE, gamma: float = GAMMA):
        self.n_flights, self.n_states = n_flights, n_states
        self.lr, self.gamma = lr, gamma
        if prior is not None and len(prior.levels) > 1:
            raise ValueError("CoordinatedQ transfers from one level (HCMARL: abstract -> ground), not a chain")
        # table levels: this one and (HCMARL's ground level) the frozen one it was transferred from, with
        # φ: this level's state -> that level's state; stacked so that one `take` reads both
        self.levels = [(n_states, np.arange(n_states))] + ([(prior.n_states, state_map)] if prior else [])
        self._tables = np.zeros((len(self.levels) << TABLE_BITS, 4), dtype=np.float32)
        if prior is not None:
            self._tables[1 << TABLE_BITS:] = prior.table
        self.table = self._tables[: 1 << TABLE_BITS]  # the one this learner updates
        u = np.uint64
        self._hash_i = np.stack([m.astype(u) * u(s) * _GOLDEN for s, m in self.levels])  # [L, state] s_i·S·G
        self._hash_j = np.stack([m.astype(u) * _GOLDEN for s, m in self.levels])  # [L, state] s_j·G
        self._hash_pair = np.array([s * s for s, _ in self.levels], dtype=u)[:, None] * _GOLDEN  # [L, 1] S²·G
        self._level_offset = np.arange(len(self.levels))[:, None]  # [L, 1]
        self._graph, self._next, self._now, self._4e = None, None, None, np.zeros(0, dtype=np.int64)

    def _graph_of(self, ev) -> _Graph:
        signature = hot_entry_codes(ev, self.n_flights)
        if self._graph is not None and np.array_equal(signature, self._graph.signature):
            return self._graph
        i, j, degree, pair = peer_edges(ev, self.n_flights)
        n, lv = self.n_flights, self._level_offset
        ij = np.concatenate([i, j])
        sides = np.concatenate([i, j + n])
        self._graph = _Graph(signature, ij, np.maximum(degree, 1), (self._hash_pair * pair.astype(np.uint64)).ravel(),
                             np.repeat(lv.ravel() << TABLE_BITS, i.size), np.concatenate([sides, sides + 2 * n]))
        if self._4e.size < i.size:
            self._4e = 4 * np.arange(2 * i.size)  # flat index of every edge's first joint action (grown, not rebuilt per graph)
        self._next = None
        return self._graph

    def _lookup(self, state: np.ndarray, g: _Graph) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """-> (rows [L·E] in the stacked tables, Q_ij(s_ij, ·) [E, 4] summed over the levels (joint action
        a_ij = 2·a_i + a_j), the frozen level's part of it)."""
        s = state[g.ij]
        n_edges = s.size // 2
        h = (self._hash_i.take(s[:n_edges], axis=1) + self._hash_j.take(s[n_edges:], axis=1)).ravel() + g.hash_edge
        rows = (h >> _SHIFT).view(np.int64) + g.level_row
        q = self._tables.take(rows, axis=0).astype(np.float64)  # take: ~10x faster than [rows]
        if len(self.levels) == 1:
            return rows, q, None
        q = q.reshape(2, -1, 4)
        return rows, q[0] + q[1], q[1]

    def values(self, state: np.ndarray, agents: np.ndarray, ev) -> np.ndarray:
        """Q_i(s_i, ·) of the acting agents from their edges (Eq 5.9) -> [agents, 2].

        When `state` is the very array the last `update` got as next state (as `run_episode` passes it) and
        the graph is unchanged, that update's lookup is reused: callers must not modify it in place."""
        g = self._graph_of(ev)
        n_edges, n = g.ij.size // 2, self.n_flights
        if self._next is not None and state is self._next[0]:  # same graph, state = the update's next state
            _, rows, frozen = self._next
            q = self.table.take(rows[:n_edges], axis=0).astype(np.float64)
            if frozen is not None:
                q += frozen
        else:
            rows, q, _ = self._lookup(state, g)
        self._now = (rows[:n_edges] * 4, q)  # the update's rows (flat, this learner's table) and current Q_ij(s_ij, ·)
        best = np.empty((2, 2, n_edges))  # [a, side, edge]: max over the other end's action
        np.maximum(q[:, 0], q[:, 1], out=best[0, 0])  # seen from i, a_i = 0: max over a_j
        np.maximum(q[:, 2], q[:, 3], out=best[1, 0])  # a_i = 1
        np.maximum(q[:, 0], q[:, 2], out=best[0, 1])  # seen from j, a_j = 0: max over a_i
        np.maximum(q[:, 1], q[:, 3], out=best[1, 1])  # a_j = 1
        sums = np.bincount(g.bins, weights=best.ravel(), minlength=4 * n).reshape(2, 2, n)
        sums = sums[:, :, agents]
        return (0.5 * (sums[:, 0] + sums[:, 1])).T

    def update(self, state, action, reward, next_state, agents) -> None:
        """Eq 5.7 on every edge of the graph the actions were chosen on."""
        g = self._graph
        n_edges = g.ij.size // 2
        if n_edges == 0:
            return
        rows_next, q_next, frozen_next = self._lookup(next_state, g)
        self._next = (next_state, rows_next, frozen_next)
        split = (reward / g.degree)[g.ij]  # r_i / |N(A_i)| at the i end, then at the j end of every edge
        target = split[:n_edges] + split[n_edges:] + self.gamma * row_max(q_next)
        a = action[g.ij]
        joint = 2 * a[:n_edges] + a[n_edges:]
        rows4, q = self._now
        current = q.ravel().take(self._4e[:n_edges] + joint)
        # add.at, not +=: two edges may share a hashed row
        np.add.at(self.table.reshape(-1), rows4 + joint, (self.lr * (target - current)).astype(np.float32))

    def transferred(self, n_states: int, state_map: np.ndarray) -> "CoordinatedQ":
        """Ground-level learner whose Q starts at this (abstract) learner's Q(φ(s))."""
        return CoordinatedQ(self.n_flights, n_states, prior=self, state_map=state_map, lr=self.lr, gamma=self.gamma)
