"""The DCB learners' episode step as numba kernels (issue 5: MIRL's vectorised episode >= 20x a per-flight loop).

The numpy step was ~55 calls on arrays of a few hundred to a few thousand elements, whose per-call overhead (1.5-3 µs)
was most of its cost; a kernel makes one pass where numpy made several calls. Each computation has one implementation,
here: `DCBProblem.evaluate` and `reward`, `Level.state`, `IndependentQ.values` and `update` and the ε-greedy choice of
`train.run_episode` call these kernels, and `independent_episode`, MIRL's whole episode (thesis state and reward) in
one call, is made of the same kernels. Results are bit for bit those of the numpy code they replaced: the same
operations in the same order (sums in entry order, as np.bincount's), the same random numbers (tests/dcb/test_compiled.py).

Compiling them all takes ~9-16 s on 2 cores, once: numba caches the machine code in __pycache__ beside this file (git-ignored),
or where that is not writable in NUMBA_CACHE_DIR or numba's user-wide cache directory (~/.cache/numba); where none
is writable, every process compiles again (numba would refuse to define a cached function at all, hence `_jit`).
The cache of a function is invalidated only by a change of its own file: so all kernels live in this one module,
which imports nothing from the others, and take the constants they use as arguments (a kernel calling a kernel or
reading a constant of another module would keep its stale compiled code after that module changed).
"""

import numpy as np
from numba import njit


def _jit(fn=None, **options):
    """njit with numba's on-disk cache where numba finds a writable cache directory, without it elsewhere."""
    if fn is None:
        return lambda f: _jit(f, **options)
    try:
        return njit(cache=True, **options)(fn)
    except RuntimeError as e:  # "cannot cache function ...: no locator available for file ..."
        if "no locator" not in str(e):
            raise
        return njit(**options)(fn)


@_jit(inline="always")
def _key(e, shifted, key_base, whole_min, flight, delay_min, within_hour):
    """Sector-hour key of entry e: ⌊(minute + d) / 60⌋ in its sector's block of hours; within_hour: the shift of
    `_Entries.shifted`, the same for delays in [0, 60]."""
    if within_hour:
        return (shifted[e] + delay_min[flight[e]]) >> 6
    return key_base[e] + (whole_min[e] + delay_min[flight[e]]) // 60


@_jit
def entry_keys(shifted, key_base, whole_min, flight, delay_min, within_hour):
    key = np.empty(flight.size, dtype=np.int64)
    for e in range(flight.size):
        key[e] = _key(e, shifted, key_base, whole_min, flight, delay_min, within_hour)
    return key


@_jit
def evaluate(delay_min, shifted, key_base, whole_min, flight, dur_min, within_hour, capacity, n_hours, n_flights, all_entries, hot_entries):
    """(status, `Evaluation`'s arrays) in two passes over the entries; status 1: a key in the grid's last (spare)
    hour, 2: a key outside the grid (counted as key 0, the caller raises). h_i and TDC_i sum in entry order, as
    np.bincount does. Always the same tuple type: an optional result costs more to return than the whole pass.
    hot_entries=False leaves entry_hot, hot_key and hot_flight empty (for a caller that needs only counts, hot, h, TDC)."""
    key = np.empty(flight.size, dtype=np.int64)
    counts = np.zeros(capacity.size, dtype=np.int64)
    status = 0
    for e in range(flight.size):
        k = _key(e, shifted, key_base, whole_min, flight, delay_min, within_hour)
        if k < 0 or k >= capacity.size:
            status, k = 2, 0
        elif all_entries and k % n_hours >= n_hours - 1:
            status = max(status, 1)
        key[e] = k
        counts[k] += 1
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


@_jit
def thesis_reward(congested_min, delay_cost, delay_min, cost_per_min, c_plus):
    """Eq 5.2-5.4 (`DCBProblem.reward`), element by element with the operations of the numpy expression it replaced."""
    r = np.empty(congested_min.size)
    for i in range(r.size):
        congestion = -cost_per_min * congested_min[i] if congested_min[i] > 0 else c_plus
        r[i] = congestion - delay_cost[i] * delay_min[i]
    return r


@_jit
def local_state(delay_min, hotspots, extra, state_step, n_extra, h_cap):
    """`Level.state` (extra: x_i, read only when n_extra > 1)."""
    s = np.empty(delay_min.size, dtype=np.int64)
    for i in range(s.size):
        s[i] = (delay_min[i] // state_step * (h_cap + 1) + min(hotspots[i], h_cap)) * n_extra + (extra[i] if n_extra > 1 else 0)
    return s


@_jit
def q_values(q, state, agents):
    """`IndependentQ.values`: Q_i(s_i, ·) of the agents -> [agents, 2]."""
    out = np.empty((agents.size, 2))
    for k in range(agents.size):
        out[k] = q[agents[k], state[agents[k]]]
    return out


@_jit
def q_update(q, state, action, reward, next_state, agents, lr, gamma):
    """`IndependentQ.update`: Eq 5.6 for every agent, in place (one row per agent: no two agents share a cell)."""
    for i in agents:
        nxt = q[i, next_state[i]]
        target = reward[i] + gamma * max(nxt[0], nxt[1])
        old = q[i, state[i], action[i]]
        q[i, state[i], action[i]] = old + lr * (target - old)


@_jit
def act(delay, agents, q, explore_draw, coin, eps, action_step):
    """ε-greedy actions of the agents (explore where the draw is below ε: the coin; else greedy, ties hold: no delay
    without a reason) -> (action [flight], the minutes it adds, the new delays)."""
    action = np.zeros(delay.size, dtype=np.int64)
    for k in range(agents.size):
        action[agents[k]] = coin[k] if explore_draw[k] < eps else q[k, 1] > q[k, 0]
    added = action * action_step
    return action, added, delay + added


@_jit
def independent_episode(rng, q, delay, state, agents, hotspots, eps, n_steps, action_step, state_step, learn, lr, gamma, delay_cost,
                        entries, h_cap, cost_per_min, c_plus):
    """`train.run_episode` for MIRL (IndependentQ) with the thesis state and reward from its first step on: the same
    draws per step (numba's Generator.random and .integers are numpy's algorithms run on the generator's own bit
    generator state), then the kernels of the step that calls the learner, in its order -> (delays, hotspots).
    entries: the relevant entries' arrays, capacity, n_hours and n_flights (`evaluate`'s arguments after the delays);
    delays stay within [0, MaxDelay] (see `run_episode`), so no key leaves the grid."""
    for _ in range(n_steps):
        if agents.size == 0:
            break
        explore_draw, coin = rng.random(agents.size), rng.integers(0, 2, agents.size)
        action, _, delay = act(delay, agents, q_values(q, state, agents), explore_draw, coin, eps, action_step)
        _, _, hot, _, _, h, tdc, _, _ = evaluate(delay, *entries, False, False)
        next_state = local_state(delay, h, delay[:0], state_step, 1, h_cap)
        if learn:
            q_update(q, state, action, thesis_reward(tdc, delay_cost, delay, cost_per_min, c_plus), next_state, agents, lr, gamma)
        state, agents, hotspots = next_state, (h > 0).nonzero()[0], hot.sum()
    return delay, hotspots
