"""The DCB learners' episode step as numba kernels (issue 5: MIRL's vectorised episode >= 20x a per-flight loop).

The numpy step was ~55 calls on arrays of a few hundred to a few thousand elements, whose per-call overhead (1.5-3 µs)
was most of its cost; a kernel makes one pass where numpy made several calls. Each computation has one implementation,
here: `DCBProblem.evaluate` and `reward`, `Level.state`, `IndependentQ.values` and `update`, `CoordinatedQ`'s peer graph,
lookup, values (Eq 5.9) and update (Eq 5.7) and the ε-greedy choice of `train.run_episode` call these kernels, and
`independent_episode` and `coordinated_episode`, MIRL's and CMARL's whole episode (thesis state and reward) in one
call, are made of the same kernels. Results are bit for bit those of the numpy code they replaced: the same
operations in the same order (sums in entry order, as np.bincount's), the same random numbers (tests/dcb/test_compiled.py).

Compiling them all takes ~19 s on 2 cores (~9-16 s before CoordinatedQ's kernels), once: numba caches the machine code in __pycache__ beside this file (git-ignored),
or where that is not writable in NUMBA_CACHE_DIR or numba's user-wide cache directory (~/.cache/numba); where none
is writable, every process compiles again (numba would refuse to define a cached function at all, hence models.jit).
The cache of a function is invalidated only by a change of its own file: so all kernels live in this one module,
which imports nothing from the others, and take the constants they use as arguments (a kernel calling a kernel or
reading a constant of another module would keep its stale compiled code after that module changed).
"""

import numpy as np

from models.jit import jit

# hold="depart": columns of a departed flight's pending value (`depart_step` writes, `depart_end` reads)
FLIGHT_STATE, FLIGHT_ACTION, FLIGHT_RETURN, FLIGHT_DISCOUNT = range(4)
FLIGHT_COLUMNS = FLIGHT_DISCOUNT + 1
# ... and of a finished edge's (`coordinated_episode` writes, `depart_edges` reads): its level-0 row, joint action, Q_ij
# when chosen, its flights i and j, their degrees, their discounted returns before that step, γ^step
EDGE_ROW, EDGE_ACTION, EDGE_Q, EDGE_I, EDGE_J, EDGE_DEGREE_I, EDGE_DEGREE_J, EDGE_RETURN_I, EDGE_RETURN_J, EDGE_DISCOUNT = range(10)
EDGE_COLUMNS = EDGE_DISCOUNT + 1


@jit(inline="always")
def _key(e, shifted, key_base, whole_min, flight, delay_min, within_hour):
    """Sector-hour key of entry e: ⌊(minute + d) / 60⌋ in its sector's block of hours; within_hour: the shift of
    `_Entries.shifted`, the same for delays in [0, 60]."""
    if within_hour:
        return (shifted[e] + delay_min[flight[e]]) >> 6
    return key_base[e] + (whole_min[e] + delay_min[flight[e]]) // 60


@jit
def entry_keys(shifted, key_base, whole_min, flight, delay_min, within_hour):
    key = np.empty(flight.size, dtype=np.int64)
    for e in range(flight.size):
        key[e] = _key(e, shifted, key_base, whole_min, flight, delay_min, within_hour)
    return key


@jit
def evaluate(delay_min, shifted, key_base, whole_min, flight, dur_min, within_hour, capacity, n_hours, n_flights, max_delay, all_entries,
             hot_entries):
    """(status, `Evaluation`'s arrays) in two passes over the entries; status 1: with all_entries, an entry in the grid's
    last (spare) hour of its sector or past it (its key would count in the next sector's hours); 2: a delay outside
    [0, max_delay] or a key outside the array (counted as key 0; the caller raises). h_i and TDC_i sum in entry order, as
    np.bincount does. Always the same tuple type: an optional result costs more to return than the whole pass.
    hot_entries=False leaves entry_hot, hot_key and hot_flight empty (for a caller that needs only counts, hot, h, TDC)."""
    key = np.empty(flight.size, dtype=np.int64)
    counts = np.zeros(capacity.size, dtype=np.int64)
    # delays outside [0, max_delay] (as unsigned: a negative one is huge), one pass over the flights: the learners'
    # entries and the keys' shift are chosen for those (all entries: any delay that stays on the grid)
    outside = False
    for f in range(delay_min.size):
        outside |= np.uint64(delay_min[f]) > np.uint64(max_delay)
    status = 2 if outside else 0
    for e in range(flight.size):
        k = _key(e, shifted, key_base, whole_min, flight, delay_min, within_hour)
        if k < 0 or k >= capacity.size:
            status, k = 2, 0
        key[e] = k
        counts[k] += 1
    if all_entries:  # its own loop: reading key_base in the loop above cost the learners' evaluation ~11 % (measured)
        for e in range(flight.size):
            if key[e] - key_base[e] >= n_hours - 1:  # the spare hour of its sector or past it, into another sector's hours
                status = max(status, 1)
    hot = counts > capacity
    n_out = flight.size if hot_entries else 0
    entry_hot = np.empty(n_out, dtype=np.bool_)
    h, tdc = np.zeros(n_flights, dtype=np.int64), np.zeros(n_flights)
    hot_key, hot_flight, n_hot = np.empty(n_out, dtype=np.int64), np.empty(n_out, dtype=np.int64), 0
    for e in range(flight.size):
        is_hot = hot[key[e]]
        if hot_entries:
            entry_hot[e] = is_hot
        if is_hot:
            f = flight[e]
            h[f] += 1
            tdc[f] += dur_min[e]
            if hot_entries:
                hot_key[n_hot], hot_flight[n_hot] = key[e], f
                n_hot += 1
    return status, counts, hot, key, entry_hot, h, tdc, hot_key[:n_hot], hot_flight[:n_hot]


@jit
def thesis_reward(congested_min, delay_cost, delay_min, cost_per_min, c_plus):
    """Eq 5.2-5.4 (`DCBProblem.reward`), element by element with the operations of the numpy expression it replaced."""
    r = np.empty(congested_min.size)
    for i in range(r.size):
        congestion = -cost_per_min * congested_min[i] if congested_min[i] > 0 else c_plus
        r[i] = congestion - delay_cost[i] * delay_min[i]
    return r


@jit
def local_state(delay_min, hotspots, extra, state_step, n_extra, h_cap):
    """`Level.state` (extra: x_i, read only when n_extra > 1)."""
    s = np.empty(delay_min.size, dtype=np.int64)
    for i in range(s.size):
        s[i] = (delay_min[i] // state_step * (h_cap + 1) + min(hotspots[i], h_cap)) * n_extra + (extra[i] if n_extra > 1 else 0)
    return s


@jit
def q_values(q, state, agents):
    """`IndependentQ.values`: Q_i(s_i, ·) of the agents -> [agents, 2]."""
    out = np.empty((agents.size, 2))
    for k in range(agents.size):
        out[k] = q[agents[k], state[agents[k]]]
    return out


@jit
def q_update(q, state, action, reward, next_state, agents, lr, gamma):
    """`IndependentQ.update`: Eq 5.6 for every agent, in place (one row per agent: no two agents share a cell)."""
    for i in agents:
        nxt = q[i, next_state[i]]
        target = reward[i] + gamma * max(nxt[0], nxt[1])
        old = q[i, state[i], action[i]]
        q[i, state[i], action[i]] = old + lr * (target - old)


@jit
def act(delay, agents, q, explore_draw, coin, eps, action_step):
    """ε-greedy actions of the agents (explore where the draw is below ε: the coin; else greedy, ties hold: no delay
    without a reason) -> (action [flight], the minutes it adds, the new delays)."""
    action = np.zeros(delay.size, dtype=np.int64)
    for k in range(agents.size):
        action[agents[k]] = coin[k] if explore_draw[k] < eps else q[k, 1] > q[k, 0]
    added = action * action_step
    return action, added, delay + added


@jit(inline="always")
def departs(action, hotspots):
    """hold="depart": an agent departs when it holds, or when its delay took it out of every hotspot."""
    return action == 0 or hotspots == 0


@jit
def depart_step(q, state, action, reward, next_state, agents, hotspots, departed, tail, learn, lr, gamma):
    """hold="depart" (`train.run_episode`): the step's agents that depart (`departs`) never act again in the episode, and
    their last action is valued by the rewards they collect from this step to the episode's end (tail: [flight] FLIGHT_*
    columns; state -1: not departed with a pending value), whose update `depart_end` makes; the other agents get Eq 5.6.
    Flights that departed at earlier steps add this step's reward to their return. reward is read only when learn."""
    if learn:
        for i in range(departed.size):
            if tail[i, FLIGHT_STATE] >= 0:
                tail[i, FLIGHT_RETURN] += tail[i, FLIGHT_DISCOUNT] * reward[i]
                tail[i, FLIGHT_DISCOUNT] *= gamma
    stay = np.empty(agents.size, dtype=np.int64)
    n_stay = 0
    for i in agents:
        if departs(action[i], hotspots[i]):
            departed[i] = True
            if learn:
                t = tail[i]
                t[FLIGHT_STATE], t[FLIGHT_ACTION], t[FLIGHT_RETURN], t[FLIGHT_DISCOUNT] = state[i], action[i], reward[i], gamma
        else:
            stay[n_stay] = i
            n_stay += 1
    if learn:
        q_update(q, state, action, reward, next_state, stay[:n_stay], lr, gamma)


@jit
def depart_end(q, tail, lr):
    """hold="depart": Eq 5.6 for every departed flight's last action, with the return it collected as its target."""
    for i in range(tail.shape[0]):
        if tail[i, FLIGHT_STATE] >= 0:
            s, a = np.int64(tail[i, FLIGHT_STATE]), np.int64(tail[i, FLIGHT_ACTION])
            q[i, s, a] += lr * (tail[i, FLIGHT_RETURN] - q[i, s, a])


@jit
def independent_episode(rng, q, delay, state, agents, hotspots, eps, n_steps, action_step, state_step, learn, lr, gamma, delay_cost,
                        entries, h_cap, cost_per_min, c_plus, depart):
    """`train.run_episode` for MIRL (IndependentQ) with the thesis state and reward from its first step on: the same
    draws per step (numba's Generator.random and .integers are numpy's algorithms run on the generator's own bit
    generator state), then the kernels of the step that calls the learner, in its order -> (delays, hotspots).
    entries: the relevant entries' arrays, capacity, n_hours, n_flights and MaxDelay (`evaluate`'s arguments after the
    delays); delays stay within [0, MaxDelay] (see `run_episode`), so `evaluate`'s status is always 0. depart: hold="depart"
    (`depart_step`), else a flight that holds acts again at the next step while it is in a hotspot."""
    departed = np.zeros(delay.size if depart else 0, dtype=np.bool_)
    tail = np.full((departed.size, FLIGHT_COLUMNS), -1.0)
    for _ in range(n_steps):
        if agents.size == 0:
            break
        explore_draw, coin = rng.random(agents.size), rng.integers(0, 2, agents.size)
        action, _, delay = act(delay, agents, q_values(q, state, agents), explore_draw, coin, eps, action_step)
        _, _, hot, _, _, h, tdc, _, _ = evaluate(delay, *entries, False, False)
        next_state = local_state(delay, h, delay[:0], state_step, 1, h_cap)
        if depart:
            reward = thesis_reward(tdc, delay_cost, delay, cost_per_min, c_plus) if learn else tdc
            depart_step(q, state, action, reward, next_state, agents, h, departed, tail, learn, lr, gamma)
            agents = ((h > 0) & ~departed).nonzero()[0]
        else:
            if learn:
                q_update(q, state, action, thesis_reward(tdc, delay_cost, delay, cost_per_min, c_plus), next_state, agents, lr, gamma)
            agents = (h > 0).nonzero()[0]
        state, hotspots = next_state, hot.sum()
    if depart and learn:
        depart_end(q, tail, lr)
    return delay, hotspots


@jit
def peer_graph(hot_key, hot_flight, n_flights):
    """`cmarl.peer_edges`: the unique pairs i < j of flights with a hot entry in the same hotspot, in increasing order
    of i·n + j, and every flight's degree |N(A_i)| -> (edges [2, E]: i, j; degree). Flight by flight in increasing
    order, its later peers collected once each (a stamp per peer) and sorted: no sort of all the pairs."""
    code = np.sort(hot_key * n_flights + hot_flight)  # hot entries by hotspot, then by flight
    flight, end = code % n_flights, np.empty(code.size, dtype=np.int64)  # end: one past the entry's hotspot's last entry
    for e in range(code.size - 1, -1, -1):
        end[e] = e + 1 if e == code.size - 1 or code[e + 1] // n_flights != code[e] // n_flights else end[e + 1]
    first = np.zeros(n_flights + 1, dtype=np.int64)  # the entries flight by flight (a counting sort)
    for e in range(code.size):
        first[flight[e] + 1] += 1
    first = np.cumsum(first)
    by_flight, filled = np.empty(code.size, dtype=np.int64), first[:-1].copy()
    for e in range(code.size):
        by_flight[filled[flight[e]]] = e
        filled[flight[e]] += 1
    stamp, peers = np.full(n_flights, -1), np.empty(n_flights, dtype=np.int64)
    edges, n_edges, degree = np.empty((2, 16), dtype=np.int64), 0, np.zeros(n_flights, dtype=np.int64)
    k = 0
    while k < by_flight.size:
        i, n_peers = flight[by_flight[k]], 0
        while k < by_flight.size and flight[by_flight[k]] == i:
            for e in range(by_flight[k] + 1, end[by_flight[k]]):  # the later entries of its hotspot: flights >= i
                j = flight[e]
                if j != i and stamp[j] != i:  # j == i: a flight entering one hotspot twice
                    stamp[j] = i
                    peers[n_peers] = j
                    n_peers += 1
            k += 1
        for m in range(1, n_peers):  # insertion sort: a flight has a few dozen peers at most
            j, at = peers[m], m
            while at > 0 and peers[at - 1] > j:
                peers[at] = peers[at - 1]
                at -= 1
            peers[at] = j
        if n_edges + n_peers > edges.shape[1]:
            edges = np.concatenate((edges[:, :n_edges], np.empty((2, max(edges.shape[1], n_peers)), dtype=np.int64)), axis=1)
        for m in range(n_peers):
            edges[0, n_edges], edges[1, n_edges] = i, peers[m]
            n_edges += 1
            degree[i] += 1
            degree[peers[m]] += 1
    return edges[:, :n_edges], degree


@jit
def joint_q(tables, state_map, level_states, edges, n_flights, state, golden, table_bits):
    """`CoordinatedQ`'s lookup of Q_ij(s_ij, ·) on every edge: for each table level l (stacked in `tables`, 2^table_bits
    rows each), row = (key·golden mod 2^64) >> (64 - table_bits) of key = ((i·n + j)·S_l + φ_l(s_i))·S_l + φ_l(s_j),
    in uint64 (wrapping as numpy's) -> (the edges' rows in level 0, the one that learns; Q_ij summed over the levels in
    float64, level 0 first, [edge, joint action 2·a_i + a_j])."""
    n_edges = edges.shape[1]
    level_rows = np.empty((level_states.size, n_edges), dtype=np.int64)
    shift = np.uint64(64 - table_bits)
    for lv in range(level_states.size):  # the rows first, then the reads: these are cache misses, many in flight at once
        n_states = np.uint64(level_states[lv])
        for e in range(n_edges):
            i, j = edges[0, e], edges[1, e]
            key = (np.uint64(i * n_flights + j) * n_states + np.uint64(state_map[lv, state[i]])) * n_states + np.uint64(state_map[lv, state[j]])
            level_rows[lv, e] = np.int64((key * golden) >> shift) + (lv << table_bits)
    q = np.empty((n_edges, 4))
    for e in range(n_edges):
        for a in range(4):
            q[e, a] = np.float64(tables[level_rows[0, e], a])
    for lv in range(1, level_states.size):
        for e in range(n_edges):
            for a in range(4):
                q[e, a] += np.float64(tables[level_rows[lv, e], a])
    return level_rows[0], q


@jit(inline="always")
def _maximum(a, b):
    """np.maximum of two numbers."""
    return a if a >= b else b


@jit(inline="always")
def _peer_best(q_hold, q_delay, held):
    """Q_ij's value for one's action given the peer's: the max over the peer's hold and delay, or its hold if it departed."""
    return q_hold if held else _maximum(q_hold, q_delay)


@jit
def coordinated_values(q, edges, n_flights, agents, departed):
    """Eq 5.9 (`CoordinatedQ.values`): Q_i(s_i, a_i) = ½ Σ_j max_{a_j} Q_ij of the agents from their edges' Q_ij (q) -> [agents, 2].
    The sums run in edge order per flight and side (i end, j end), as the np.bincount they replaced. departed
    (hold="depart", else empty): a departed peer j adds no more delay, so its a_j is 0, not the max."""
    fixed = departed.size > 0
    sums = np.zeros((2, 2, n_flights))  # [a, side, flight]
    for e in range(edges.shape[1]):
        i, j = edges[0, e], edges[1, e]
        held_i, held_j = fixed and departed[i], fixed and departed[j]
        sums[0, 0, i] += _peer_best(q[e, 0], q[e, 1], held_j)  # seen from i, a_i = 0: max over a_j
        sums[1, 0, i] += _peer_best(q[e, 2], q[e, 3], held_j)
        sums[0, 1, j] += _peer_best(q[e, 0], q[e, 2], held_i)  # seen from j, a_j = 0: max over a_i
        sums[1, 1, j] += _peer_best(q[e, 1], q[e, 3], held_i)
    out = np.empty((agents.size, 2))
    for k in range(agents.size):
        for a in range(2):
            out[k, a] = 0.5 * (sums[a, 0, agents[k]] + sums[a, 1, agents[k]])
    return out


@jit
def coordinated_update(tables, state_map, level_states, edges, degree, n_flights, rows, q, action, reward, next_state, lr, gamma,
                       golden, table_bits, departed, gone, hotspots):
    """Eq 5.7 (`CoordinatedQ.update`) on every edge, in place in level 0 of `tables`: rows and q are the edges' `joint_q`
    at the state the actions were chosen in. All targets are read before any row is written, then the float32 rows
    are updated in edge order (two edges can share a hashed row), as np.add.at did -> the edges left to `depart_edges`.
    hold="depart" (else departed and gone are empty): departed, the flights departed before this step, gone, those and
    the ones departing at it; hotspots: h_i after the step. A departed flight's action is 0 (it adds no more delay), in
    the bootstrap too; an edge of two departed flights, which acted neither, is left alone. An edge done after this
    step - both its flights gone, or one gone and in no hotspot (out of the graph for good: Q_ij at s' would never
    be learned) - is not updated here but returned, its target being the rewards its flights collect until the episode
    ends (`depart_edges`), as a departed flight's in MIRL (`depart_step`)."""
    _, q_next = joint_q(tables, state_map, level_states, edges, n_flights, next_state, golden, table_bits)
    depart = gone.size > 0
    step = np.zeros(edges.shape[1], dtype=np.float32)  # 0: the edge is left alone here
    pending, n_pending = np.empty(edges.shape[1] if depart else 0, dtype=np.int64), 0
    for e in range(step.size):
        i, j = edges[0, e], edges[1, e]
        if depart and ((gone[i] and gone[j]) or (gone[i] and hotspots[i] == 0) or (gone[j] and hotspots[j] == 0)):
            if not (departed[i] and departed[j]):
                pending[n_pending] = e
                n_pending += 1
            continue
        if depart and (gone[i] or gone[j]):  # the bootstrap's best joint action with the gone flight's a = 0
            best = -np.inf
            for a in range(4):
                if not ((gone[i] and a >= 2) or (gone[j] and a % 2 == 1)):
                    best = _maximum(best, q_next[e, a])
        else:
            best = _maximum(_maximum(_maximum(q_next[e, 0], q_next[e, 1]), q_next[e, 2]), q_next[e, 3])
        target = reward[i] / degree[i] + reward[j] / degree[j] + gamma * best
        step[e] = np.float32(lr * (target - q[e, 2 * action[i] + action[j]]))
    for e in range(step.size):
        tables[rows[e], 2 * action[edges[0, e]] + action[edges[1, e]]] += step[e]
    return pending[:n_pending]


@jit
def depart_edges(tables, tail, returns, lr):
    """hold="depart": Eq 5.7 for every edge `coordinated_update` returned, with what its two flights collected from that
    step to the episode's end, each share divided by its degree then, as the target. tail: [edge] EDGE_* columns;
    returns: every flight's Σ_t γ^t r_t over the episode. Rows updated in order, as np.add.at does."""
    for k in range(tail.shape[0]):
        t = tail[k]
        i, j = np.int64(t[EDGE_I]), np.int64(t[EDGE_J])
        collected = (returns[i] - t[EDGE_RETURN_I]) / t[EDGE_DEGREE_I] + (returns[j] - t[EDGE_RETURN_J]) / t[EDGE_DEGREE_J]
        tables[np.int64(t[EDGE_ROW]), np.int64(t[EDGE_ACTION])] += np.float32(lr * (collected / t[EDGE_DISCOUNT] - t[EDGE_Q]))


@jit
def coordinated_episode(rng, tables, state_map, level_states, golden, table_bits, delay, state, agents, hot_key, hot_flight, hotspots, eps,
                        n_steps, action_step, state_step, learn, lr, gamma, delay_cost, entries, h_cap, cost_per_min, c_plus, depart):
    """`train.run_episode` for CMARL and HCMARL (CoordinatedQ) with the thesis state and reward, as `independent_episode`
    for MIRL: the peer graph of the step's hot entries (kept while they stay the same), Eq 5.9, the draws and the
    ε-greedy choice, the evaluation, Eq 5.7 -> (delays, hotspots). hot_key, hot_flight: the hot entries at the start.
    depart: hold="depart" - the step's agents that held, or whose delay took them out of every hotspot, depart and never
    act again; a departed flight stays in its hotspots' graph as a peer that holds (`coordinated_values`,
    `coordinated_update`, `depart_edges`); else a flight that holds acts again at the next step while it is in a hotspot."""
    n_flights = delay.size
    signature, (edges, degree) = hot_key[:0], peer_graph(hot_key[:0], hot_flight[:0], n_flights)  # none yet (typed as the loop's)
    departed = np.zeros(n_flights if depart else 0, dtype=np.bool_)
    returns, discount = np.zeros(departed.size), 1.0  # Σ_t γ^t r_t of every flight so far, γ^t
    tail, n_tail = np.empty((16 if depart and learn else 0, EDGE_COLUMNS)), 0  # `depart_edges`'s
    for _ in range(n_steps):
        if agents.size == 0:
            break
        codes = hot_key * n_flights + hot_flight
        if codes.size != signature.size or (codes != signature).any():
            signature, (edges, degree) = codes, peer_graph(hot_key, hot_flight, n_flights)
        rows, q = joint_q(tables, state_map, level_states, edges, n_flights, state, golden, table_bits)
        values = coordinated_values(q, edges, n_flights, agents, departed)
        explore_draw, coin = rng.random(agents.size), rng.integers(0, 2, agents.size)
        action, _, delay = act(delay, agents, values, explore_draw, coin, eps, action_step)
        _, _, hot, _, _, h, tdc, hot_key, hot_flight = evaluate(delay, *entries, False, True)
        next_state = local_state(delay, h, delay[:0], state_step, 1, h_cap)
        gone = departed.copy()
        if depart:
            for i in agents:
                gone[i] = departs(action[i], h[i])
        if learn:
            reward = thesis_reward(tdc, delay_cost, delay, cost_per_min, c_plus)
            pending = coordinated_update(tables, state_map, level_states, edges, degree, n_flights, rows, q, action, reward, next_state,
                                         lr, gamma, golden, table_bits, departed, gone, h)
            if n_tail + pending.size > tail.shape[0]:
                tail = np.concatenate((tail[:n_tail], np.empty((max(tail.shape[0], pending.size), EDGE_COLUMNS))))
            for e in pending:
                i, j = edges[0, e], edges[1, e]
                a = 2 * action[i] + action[j]
                t = tail[n_tail]
                t[EDGE_ROW], t[EDGE_ACTION], t[EDGE_Q], t[EDGE_I], t[EDGE_J] = rows[e], a, q[e, a], i, j
                t[EDGE_DEGREE_I], t[EDGE_DEGREE_J], t[EDGE_RETURN_I], t[EDGE_RETURN_J], t[EDGE_DISCOUNT] = degree[i], degree[j], returns[i], returns[j], discount
                n_tail += 1
            if depart:
                returns += discount * reward
                discount *= gamma
        departed = gone
        state, agents, hotspots = next_state, ((h > 0) & ~departed if depart else h > 0).nonzero()[0], hot.sum()
    if n_tail:
        depart_edges(tables, tail[:n_tail], returns, lr)
    return delay, hotspots
