"""CMARL: collaborative Q-learning on the coordination graph (thesis §5.4.2), and its hierarchical
transfer used by HCMARL (§5.5.2).

Peers are flights that share a hotspot; the graph is rebuilt whenever delays move a hot entry.
Every edge (i, j) has a joint Q-function over the joint state s_ij = (s_i, s_j) and joint action:

    Q_ij(s_ij, a_ij) <- (1 - η) Q_ij + η [ r_i/|N(A_i)| + r_j/|N(A_j)| + γ Q_ij(s'_ij, a*_ij) ]   (Eq 5.7, 5.12)
    Q_i(s_i, a_i)  = ½ Σ_{j ∈ N(A_i)} max_{a_j} Q_ij(s_ij, (a_i, a_j))                          (Eq 5.9)
    a*_i = argmax_{a_i} Q_i(s_i, a_i)                                                            (Eq 5.8)

a*_ij in the target is the best joint action of the edge's own table at s'_ij (the next step's graph
is not known yet when the edge is updated).

hold="depart" (§5.4's "until it departs", see train.py; kernels.coordinated_episode): a flight that holds, or leaves
every hotspot, never acts again in the episode, and stays in the graph while it is in a hotspot, as a peer whose action
is 0: Eq 5.9's max and Eq 5.7's a*_ij range over the acting flights' actions only, and Eq 5.7 goes on while one of the
edge's flights acts. An edge done for the episode - both its flights departed, or one departed and in no hotspot (the
edge leaves the graph, Q_ij(s'_ij) would never be learned) - takes as the target of its last joint action what the two
flights collect until the episode ends, each share divided by its degree then: Σ_k γ^k (r_i,t+k/|N(A_i)| + r_j,t+k/|N(A_j)|),
MIRL's rule for a departed flight (Eq 5.6 with the return as target) applied to Eq 5.7's target.

Storage: the joint tables Q_ij are tabular but sparse (a day has thousands of possible peer pairs
and (states)^2 x 4 entries each), so they live in one [2^20, 4] array whose row is a multiplicative
hash of the key ((i·n + j)·S + s_i)·S + s_j and whose 4 columns are the joint actions (one cache line
per edge lookup). Two keys can share a row (2^20 rows; the visited joint states are a few hundred
thousand at most, so collisions are rare) - the same approximation as CMAC hashing in Sutton & Barto §9.5.4.
HCMARL's transfer: a ground lookup is Q_abstract(φ(s_ij)) + ΔQ_ground(s_ij), with ΔQ starting at 0 -
exactly "copy the abstract Q-values down", done lazily for the keys actually visited.

Speed: a ground step has ~100-600 hot entries and ~1,000 edges, too little data per call for numpy to pay off, so
the peer graph, the lookup (hash and read of every level's row), Eq 5.9 and Eq 5.7 are numba kernels
(models/dcb/kernels.py: peer_graph, joint_q, coordinated_values, coordinated_update), one pass over the edges each,
and with the thesis state and reward `train.run_episode` runs the whole episode as one kernel call
(kernels.coordinated_episode). The results are bit for bit those of the numpy version they replaced: float64 sums in
edge order as np.bincount's, every target read before any row is written and the float32 rows updated edge by edge
as np.add.at's (two edges can share a row). The graph is kept while the hot entries stay the same (about a third of
the steps). train(cap95, "CMARL" / "HCMARL", 0, 200): 3.5 / 4.2 s with the numpy learner, 1.3 / 1.6 s (2026-11-24,
load ~2); the two lookups (the table reads are cache misses) are ~2/3 of what is left.
"""

from dataclasses import dataclass

import numpy as np

from models.dcb import kernels
from models.dcb.mirl import GAMMA, LEARNING_RATE

TABLE_BITS = 20
GOLDEN = np.uint64(0x9E3779B97F4A7C15)  # the multiplicative hash's factor (2^64 / golden ratio)
_NONE_DEPARTED = np.zeros(0, dtype=np.bool_)  # the kernels' hold="wait" (hold="depart" runs only in kernels.coordinated_episode)


def hot_entry_codes(ev, n_flights: int) -> np.ndarray:
    """hotspot · n + flight of every hot entry: the graph depends on nothing else."""
    return ev.hot_key * n_flights + ev.hot_flight


def peer_edges(ev, n_flights: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Coordination graph: unique pairs (i < j, sorted) of flights with an entry in the same hotspot
    -> (i, j, every flight's degree |N(A_i)|, pair code i·n + j)."""
    (i, j), degree = kernels.peer_graph(ev.hot_key, ev.hot_flight, n_flights)
    return i, j, degree, i * n_flights + j


@dataclass
class _Graph:
    """One coordination graph, reused while the hot entries stay the same."""

    signature: np.ndarray  # [hot entry] hot_entry_codes
    edges: np.ndarray  # [2, edge] i, j (i < j), in increasing order of i·n + j
    degree: np.ndarray  # [flight] |N(A_i)|


class CoordinatedQ:
    def __init__(self, n_flights: int, n_states: int, prior: "CoordinatedQ | None" = None, state_map: np.ndarray | None = None,
                 lr: float = LEARNING_RATE, gamma: float = GAMMA):
        self.n_flights, self.n_states = n_flights, n_states
        self.lr, self.gamma = lr, gamma
        if prior is not None and len(prior.levels) > 1:
            raise ValueError("CoordinatedQ transfers from one level (HCMARL: abstract -> ground), not a chain")
        # table levels: this one and (HCMARL's ground level) the frozen one it was transferred from, with
        # φ: this level's state -> that level's state; stacked so that one lookup reads both
        self.levels = [(n_states, np.arange(n_states))] + ([(prior.n_states, state_map)] if prior else [])
        self._tables = np.zeros((len(self.levels) << TABLE_BITS, 4), dtype=np.float32)
        if prior is not None:
            self._tables[1 << TABLE_BITS:] = prior.table
        self.table = self._tables[: 1 << TABLE_BITS]  # the one this learner updates
        # the kernels' view of the tables: the stacked tables, φ_l [level, state] and S_l
        self.lookup = (self._tables, np.stack([m for _, m in self.levels]), np.array([s for s, _ in self.levels]))
        self._graph, self._now = None, None

    def _graph_of(self, ev) -> _Graph:
        signature = hot_entry_codes(ev, self.n_flights)
        if self._graph is None or not np.array_equal(signature, self._graph.signature):
            self._graph = _Graph(signature, *kernels.peer_graph(ev.hot_key, ev.hot_flight, self.n_flights))
        return self._graph

    def values(self, state: np.ndarray, agents: np.ndarray, ev) -> np.ndarray:
        """Q_i(s_i, ·) of the acting agents from their edges (Eq 5.9) -> [agents, 2]."""
        g = self._graph_of(ev)
        # the edges' rows and Q_ij(s_ij, ·) summed over the levels (joint action a_ij = 2·a_i + a_j), kept for the update
        self._now = kernels.joint_q(*self.lookup, g.edges, self.n_flights, state, GOLDEN, TABLE_BITS)
        return kernels.coordinated_values(self._now[1], g.edges, self.n_flights, agents, _NONE_DEPARTED)

    def update(self, state, action, reward, next_state, agents) -> None:
        """Eq 5.7 on every edge of the graph the actions were chosen on."""
        g = self._graph
        kernels.coordinated_update(*self.lookup, g.edges, g.degree, self.n_flights, *self._now, action, reward, next_state,
                                   self.lr, self.gamma, GOLDEN, TABLE_BITS, _NONE_DEPARTED, _NONE_DEPARTED, next_state[:0])

    def transferred(self, n_states: int, state_map: np.ndarray) -> "CoordinatedQ":
        """Ground-level learner whose Q starts at this (abstract) learner's Q(φ(s))."""
        return CoordinatedQ(self.n_flights, n_states, prior=self, state_map=state_map, lr=self.lr, gamma=self.gamma)
