"""The urban env's per-decision arithmetic as numba kernels (issue 4: the env's vehicle-steps per second against plain
SUMO's on Sc1): the lane facts, state (Eq 4.2) and reward (Eq 4.3-4.7, i-MARL's Eq 3.2-3.3) of every vehicle, a
snapshot's derived columns, the held accelerations and the rollout's Q-network layers.

With a handful of vehicles on the road (Sc1: ~16) the numpy version was dozens of calls per 1 s decision on arrays of
that size, each costing its 1-3 µs whatever the size: a kernel makes one pass over the vehicles instead. Each
computation has one implementation, here; models.urban.env's `conflict_matrix`, `junction_terms`, `safe_dist` and
`reward` call these kernels. Results are bit for bit those of the numpy code they replaced: the same float operations
in the same order (tests/urban/test_env.py's recorded episodes, tests/urban/test_kernels.py).

Caching as in models.dcb.kernels (both use models.jit): numba keeps the machine code in __pycache__ beside
this file (or NUMBA_CACHE_DIR, ~/.cache/numba); a process that finds none compiles them, ~5-10 s on 2 cores (11.7 s
measured at a load average of 3.5), once. A cache is invalidated only by a change of this file, so the kernels import
nothing else from the project and take the env's constants as arguments (`params`, a tuple in the order of `PARAMS`).
No kernel is recursive: numba's cache of a recursive function crashed the process when loaded (measured).
"""

import ctypes

import numpy as np
from llvmlite import ir
from numba import types
from numba.core.extending import intrinsic

from models.jit import jit

# the floats in `params`, in order (models.urban.env.KERNEL_PARAMS builds the tuple from the env's constants)
PARAMS = ("safe_dist_m", "safe_headway_s", "action_s", "max_brake_mps2", "c1", "c2", "c3", "beta1", "beta2", "min_fveh_dist_m",
          "max_f_d", "inter_time_s", "pos_scale_m", "leader_scale_m")
# each one's position in `params`, by name (a reordered PARAMS cannot swap two constants; numba freezes these ints)
(SAFE_DIST_M, SAFE_HEADWAY_S, ACTION_S, MAX_BRAKE_MPS2, C1, C2, C3, BETA1, BETA2, MIN_FVEH_DIST_M, MAX_F_D, INTER_TIME_S,
 POS_SCALE_M, LEADER_SCALE_M) = (PARAMS.index(n) for n in ("safe_dist_m", "safe_headway_s", "action_s", "max_brake_mps2", "c1", "c2", "c3",
                                                          "beta1", "beta2", "min_fveh_dist_m", "max_f_d", "inter_time_s", "pos_scale_m",
                                                          "leader_scale_m"))
RULES = ("thesis", "headway", "stopping")  # safe_dist rule codes


@jit
def lane_facts(lane_code, lane_pos, route_index, route, route_edges, lane_road, lane_junction, lane_internal, lane_len, lane_centre_m):
    """Per vehicle, from its lane's row of NetIndex's tables: road code, junction ahead or under it (-1: none, or the
    vehicle is on its route's last road), inside a junction?, distance to the stop line (0 inside), inter_dist (Eq 4.1:
    to the junction's centre, 0 once past it) and on its last road? (route: route rows, route_edges: edges per route)."""
    n = lane_code.size
    road, junction = np.empty(n, np.int64), np.empty(n, np.int64)
    internal, last_road = np.empty(n, np.bool_), np.empty(n, np.bool_)
    dist, centre_dist = np.empty(n), np.empty(n)
    for i in range(n):
        c = lane_code[i]
        road[i], internal[i] = lane_road[c], lane_internal[c]
        last_road[i] = route_index[i] >= route_edges[route[i]] - 1 and not internal[i]
        junction[i] = -1 if last_road[i] else lane_junction[c]
        dist[i] = 0.0 if internal[i] else max(lane_len[c] - lane_pos[i], 0.0)
        centre_dist[i] = max(lane_centre_m[c] - lane_pos[i], 0.0)
    return road, junction, internal, dist, centre_dist, last_road


@jit
def conflict_matrix(junction, road, centre_dist_m, speed, inter_time_s):
    """[n, n]: vehicle i is predicted to collide with j (see models.urban.env.conflict_matrix)."""
    n = junction.size
    inter_time = np.empty(n)
    for i in range(n):
        inter_time[i] = centre_dist_m[i] / max(speed[i], 0.1)
    out = np.zeros((n, n), np.bool_)
    for i in range(n):
        if junction[i] < 0:
            continue
        for j in range(n):
            out[i, j] = junction[j] == junction[i] and road[j] != road[i] and abs(inter_time[i] - inter_time[j]) < inter_time_s
    return out


@jit
def junction_terms(junction, road, centre_dist_m, speed, incoming_lanes, inter_time_s):
    """col_term and density of every vehicle (Eq 4.2, §4.2.1): predicted collisions > 0, and their count per incoming lane."""
    conflict = conflict_matrix(junction, road, centre_dist_m, speed, inter_time_s)
    n = junction.size
    col_term, density = np.zeros(n), np.zeros(n)
    for i in range(n):
        count = conflict[i].sum()
        col_term[i] = 1.0 if count > 0 else 0.0
        if junction[i] >= 0:
            density[i] = count / incoming_lanes[junction[i]]
    return col_term, density


@jit(inline="always")
def _safe_dist(v, rule, params):
    safe_m, headway_s, action_s, brake_mps2 = params[SAFE_DIST_M], params[SAFE_HEADWAY_S], params[ACTION_S], params[MAX_BRAKE_MPS2]
    if rule == 0:
        return safe_m
    if rule == 1:
        return max(safe_m, v * headway_s)
    return max(safe_m, v * action_s + v**2 / (2 * brake_mps2))


@jit
def safe_dist(speed, rule, params):
    """safe_dist of Eq 4.5-4.7 / Eq 3.3 per vehicle; rule: code in RULES."""
    out = np.empty(speed.size)
    for i in range(speed.size):
        out[i] = _safe_dist(speed[i], rule, params)
    return out


@jit
def reward(col, speed, vmax, fveh_dist, col_term, rule, params):
    """Non-terminal reward of every vehicle: col-MARL's Eq 4.4-4.7 (col) or i-MARL's Eq 3.2-3.3 with C = 1."""
    c1, c2, c3, beta1, beta2 = params[C1], params[C2], params[C3], params[BETA1], params[BETA2]
    min_d, max_f_d = params[MIN_FVEH_DIST_M], params[MAX_F_D]
    out = np.empty(speed.size)
    for i in range(speed.size):
        fv, sd, d = speed[i] / vmax, _safe_dist(speed[i], rule, params), fveh_dist[i]
        near = d >= 0 and d < sd
        if not col:
            out[i] = -(beta2 + fv) * (sd - d) if near else beta1 * fv
            continue
        f_d = min(sd / max(min(d, sd), min_d), max_f_d)
        if col_term[i] > 0:
            out[i] = -(c3 + fv) * f_d if near else -(c2 + fv)
        else:
            out[i] = -(c1 + fv) * f_d if near else fv
    return out


@jit(inline="always")
def _scaled(term, scale):
    return term / scale if term >= 0 else -1.0  # -1: no front vehicle (speed and pos are never negative)


@jit
def individual_state(speed, dist, leader_dist, leader_speed, vmax, params):
    """[vel / vel_max, pos / pos scale, fveh_dist / leader scale, fveh_vel / vel_max] of every vehicle, [n, 4]."""
    pos_scale, leader_scale = params[POS_SCALE_M], params[LEADER_SCALE_M]
    out = np.empty((speed.size, 4))
    for i in range(speed.size):
        out[i, 0], out[i, 1] = _scaled(speed[i], vmax), _scaled(dist[i], pos_scale)
        out[i, 2], out[i, 3] = _scaled(leader_dist[i], leader_scale), _scaled(leader_speed[i], vmax)
    return out


@jit
def state_reward(col, speed, dist, leader_dist, leader_speed, junction, road, centre_dist_m, incoming_lanes, vmax, rule, params):
    """State (float32; col: Eq 4.2's 6 terms, else its first 4) and non-terminal reward of every vehicle."""
    state = np.empty((speed.size, 6 if col else 4), np.float32)
    state[:, :4] = individual_state(speed, dist, leader_dist, leader_speed, vmax, params)
    col_term = np.zeros(speed.size)
    if col:
        col_term, density = junction_terms(junction, road, centre_dist_m, speed, incoming_lanes, params[INTER_TIME_S])
        state[:, 4], state[:, 5] = col_term, density
    return state, reward(col, speed, vmax, leader_dist, col_term, rule, params)


@jit
def observe(lane_code, lane_pos, route_index, route, route_edges, lane_road, lane_junction, lane_internal, lane_len, lane_centre_m,
            col, speed, leader_dist, leader_speed, incoming_lanes, vmax, rule, params):
    """lane_facts then state_reward in one call: state, reward and on its last road? of every vehicle. In the env's loop a
    kernel call costs ~0.5 µs per array it returns (numba unpickles the array type for each) on top of its dispatch."""
    road, junction, _, dist, centre_dist, last_road = lane_facts(lane_code, lane_pos, route_index, route, route_edges, lane_road,
                                                                 lane_junction, lane_internal, lane_len, lane_centre_m)
    state, reward = state_reward(col, speed, dist, leader_dist, leader_speed, junction, road, centre_dist, incoming_lanes, vmax, rule, params)
    return state, reward, last_road


@jit
def dense(x, w, b, agent):
    """x [n, i] -> x w[agent] + b[agent], [n, o]: one dense layer of each row's own route agent (weights stacked as
    [agent, i, o]); float32, summed over i in order as np.einsum does (the same Q values to the bit). Few outputs (the
    Q layer's 5): four rows at a time, their sums in registers (summed through memory, each output's chain of i additions
    waited on the last: 2x slower); many (the hidden layer): over the outputs innermost, which vectorises."""
    n, o = x.shape[0], w.shape[2]
    out = np.zeros((n, o), np.float32)
    blocked = n - n % 4 if o < 16 else 0  # rows summed four at a time
    for r in range(0, blocked, 4):
        k0, k1, k2, k3 = agent[r], agent[r + 1], agent[r + 2], agent[r + 3]
        for j in range(o):
            s0 = s1 = s2 = s3 = np.float32(0.0)
            for m in range(x.shape[1]):
                s0 += x[r, m] * w[k0, m, j]
                s1 += x[r + 1, m] * w[k1, m, j]
                s2 += x[r + 2, m] * w[k2, m, j]
                s3 += x[r + 3, m] * w[k3, m, j]
            out[r, j], out[r + 1, j], out[r + 2, j], out[r + 3, j] = s0, s1, s2, s3
    for r in range(blocked, n):
        k = agent[r]
        for m in range(x.shape[1]):
            xm = x[r, m]
            for j in range(o):
                out[r, j] += xm * w[k, m, j]
    for r in range(n):
        for j in range(o):
            out[r, j] += b[agent[r], j]
    return out


@jit
def accelerations(action, is_car, speed, car_mps2, heavy_mps2, vmax, action_s):
    """Table 4.1's acceleration of each vehicle's action, clipped so that 0 <= speed <= vmax over the held action."""
    out = np.empty(action.size)
    for i in range(action.size):
        a = car_mps2[action[i]] if is_car[i] else heavy_mps2[action[i]]
        low, high = -speed[i] / action_s, (vmax - speed[i]) / action_s
        a = a if a > low else low  # np.clip's comparisons: clipping 0 at -0.0 gives -0.0, as SUMO was told before
        out[i] = a if a < high else high
    return out


PW_BLOCK = 128  # numpy's PW_BLOCKSIZE: its pairwise summation splits longer arrays in two


@jit
def _pairwise_block(a, lo, n):
    """numpy's sum of a[lo:lo + n] for n <= PW_BLOCK (loops_utils.h.src): 8 interleaved accumulators from 8 values on."""
    if n < 8:
        res = -0.0  # numpy's start: a sum of only -0 stays -0
        for i in range(lo, lo + n):
            res += a[i]
        return res
    r = a[lo:lo + 8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += a[lo + i + j]
        i += 8
    res = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    for k in range(lo + i, lo + n):
        res += a[k]
    return res


@jit
def numpy_sum(a):
    """a.sum() of a 1-D float64 array, to the bit: numpy adds to 0 the pairwise sum, whose halves (a multiple of 8 values
    on the left) split until at most PW_BLOCK values; the tree is walked with a stack (no recursive kernels)."""
    if a.size <= PW_BLOCK:
        return 0.0 + _pairwise_block(a, 0, a.size)
    todo, sums = [(0, a.size, False)], [0.0]  # (start, length, both halves summed?), finished sums (after the first 0)
    while todo:
        lo, n, halves_done = todo.pop()
        if halves_done:
            right = sums.pop()
            sums.append(sums.pop() + right)
        elif n <= PW_BLOCK:
            sums.append(_pairwise_block(a, lo, n))
        else:
            half = n // 2 - n // 2 % 8
            todo += [(lo, n, True), (lo + half, n - half, False), (lo, half, False)]  # the left half first
    return sums[0] + sums[1]


@jit
def snapshot_columns(rows, lane_len, min_gap_m):
    """The columns of a snapshot that follow from the getters' rows (models.urban.sim.Simulation.snapshot): lane code and
    route index as integers, lane length, fuel volume rate (ml/s) and the leader's bumper-to-bumper gap (-1: no leader;
    getLeader's distance excludes the follower's minGap, added back: a leader closer than minGap is not "no leader"); and
    the sums of the speeds and fuel rates for the episode's metrics (numpy's `sum`, to the bit)."""
    n = rows.shape[1]
    code, route_index = np.empty(n, np.int64), np.empty(n, np.int64)
    length, fuel_mlps, leader_dist = np.empty(n), np.empty(n), np.empty(n)
    for i in range(n):
        code[i], route_index[i] = int(rows[5, i]), int(rows[2, i])
        length[i], fuel_mlps[i] = lane_len[code[i]], rows[3, i] / rows[4, i]
        gap = rows[7, i] + min_gap_m
        leader_dist[i] = (0.0 if 0.0 > gap else gap) if rows[6, i] > 0 else -1.0  # Python's max(gap, 0.0), as it was
    return code, route_index, length, fuel_mlps, leader_dist, numpy_sum(rows[0]), numpy_sum(fuel_mlps)


def bit_generator(rng: np.random.Generator) -> tuple:
    """(state, next_double, next_uint32) of rng's bit generator as addresses, for `epsilon_greedy`: it draws with numpy's
    own C functions on the generator's own state, so the generator goes on exactly as if numpy had drawn (the rollout's
    `rng.integers` alone was ~6 µs of Python around a few nanoseconds of drawing). Valid while rng lives."""
    c = rng.bit_generator.ctypes
    return c.state_address, ctypes.cast(c.next_double, ctypes.c_void_p).value, ctypes.cast(c.next_uint32, ctypes.c_void_p).value


def _draw(ret):
    """An intrinsic calling a bit generator's C draw function (address) on its state (address), returning `ret`: both
    arrive as integers, cast in the generated code to `ret (*)(void *)` and `void *`, and called directly. Why not numba's
    own support of a Generator argument (as models/dcb/kernels.py, once per episode): it draws the same, but unboxes
    the generator through its Python ctypes attributes on every call, ~16 µs per decision against ~1.4 µs here
    (16 rows, 5 actions, timeit, 2026-11-24 09:28 UTC, load 4.8)."""

    @intrinsic
    def call(typingctx, fn, state):
        def codegen(context, builder, sig, args):
            ptr = ir.IntType(8).as_pointer()
            fn_type = ir.FunctionType(context.get_value_type(ret), [ptr])
            return builder.call(builder.inttoptr(args[0], fn_type.as_pointer()), [builder.inttoptr(args[1], ptr)])

        return ret(fn, state), codegen

    return call


_next_double, _next_uint32 = _draw(types.float64), _draw(types.uint32)


@jit
def epsilon_greedy(q, epsilon, bitgen, allowed):
    """Each row's action under ε-greedy exploration, drawn from the generator of `bitgen` (`bit_generator`) exactly as
    numpy's `rng.random(n) < epsilon` (explore?) then, without a mask, `rng.integers(0, n_actions, n)` (the exploring
    rows' actions) and else argmax q; with a mask `allowed` [n, n_actions] (the safety layer), `rng.random((n,
    n_actions))` and the exploring rows take the argmax of those draws over the allowed actions, the others their best
    allowed q. Same draws, same order, same ties (the first) as the numpy expressions: the same episodes to the bit."""
    state, next_double, next_uint32 = bitgen
    n, n_actions = q.shape
    explore = np.empty(n, np.bool_)
    for i in range(n):
        explore[i] = _next_double(next_double, state) < epsilon
    action = np.empty(n, np.int64)
    if allowed is None:
        # numpy's integers(0, n_actions): Lemire's method on 32-bit draws (random_bounded_uint64_fill); no draw for one action
        span = np.uint64(n_actions)
        threshold = (np.uint64(0xFFFFFFFF) - np.uint64(n_actions - 1)) % span
        for i in range(n):
            draw = np.uint64(0)
            if n_actions > 1:
                m = np.uint64(_next_uint32(next_uint32, state)) * span
                while (m & np.uint64(0xFFFFFFFF)) < threshold:
                    m = np.uint64(_next_uint32(next_uint32, state)) * span
                draw = m >> np.uint64(32)
            action[i] = draw if explore[i] else np.argmax(q[i])
        return action
    u = np.empty((n, n_actions))
    for i in range(n):
        for j in range(n_actions):
            u[i, j] = _next_double(next_double, state)
    for i in range(n):
        action[i] = np.argmax(u[i] * allowed[i]) if explore[i] else np.argmax(np.where(allowed[i], q[i], -np.inf))
    return action
