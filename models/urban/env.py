"""Multi-agent environment over libsumo, PettingZoo parallel API (thesis §4.2).

PettingZoo agents are the vehicles on the road still approaching a junction; each belongs to a *route
agent* (route x vehicle class, `infos[vehicle]["route_agent"]`) whose policy drives all its vehicles.
Every `ACTION_S` = 1 s each vehicle picks one of 5 accelerations (Table 4.1), held while SUMO runs
sub-steps of 0.2 s so that crossing collisions are detected.

State (Eq 4.2), scaled to about [-1, 1] for the networks:
    s = [vel / vel_max, pos / 200 m, fveh_dist / 200 m (-1: none), fveh_vel / vel_max (-1: none), col_term, density]
pos is the distance still to go to the junction ahead (0 inside a junction). col_term and density are
computed centrally per junction, for all vehicles at once: inter_time = inter_dist / vel with inter_dist the
distance to the junction's centre (Eq 4.1; 0 once past it); col_term = 1 when a vehicle on another road
approaching the same junction has |Δinter_time| < 1.5 s; density = the number of such vehicles / the
junction's incoming lanes (§4.2.1). Vehicles on the same road are left out of col_term: they cannot cross
each other's path, the front-vehicle terms cover them.

Variants: "col" (col-MARL, reward Eq 4.3-4.7) and "ind" (i-MARL ablation: the first 4 state terms only,
reward Eq 3.2-3.3 without a collision prediction, C = 1).

Terminal rewards: -L on a collision or a teleport; +L when the vehicle has crossed its last junction.
From there it drives its last road under a fixed rule (max acceleration up to vel_max, §4.3.1) with
SUMO's safety checks back on, and it no longer is a PettingZoo agent.

safe_dist (Eq 4.5-4.7, i-MARL's Eq 3.3): the thesis's 20 m on every road by default (SAFE_DIST_RULE);
"headway" and "stopping" make it grow with speed (measured: no fewer collisions after the demo budget,
docs/history/urban.md, first session).

Car-following safety (leader_guard=True, the default): SUMO caps each agent vehicle's commanded speed at the
safe speed behind its leader (speed mode 97 with Krauss vehicle types: the speed from which it can still stop
behind a leader braking hard), and nothing else: no right of way at the junctions, no speed limits, the agent's
acceleration otherwise executed as is. The thesis's agents learn to cross unsignalized junctions; car following is
left to the simulator as for its IDM baseline, which "shares the same safety settings as the proposed method (i.e.,
unsignalized intersections, no right-way rule, and so on)" (§4.3.1; docs/history/urban.md, second session). leader_guard=False: every
SUMO check off (speed mode 32), rear-end collisions possible.
"""

import functools
import re
from dataclasses import dataclass
from pathlib import Path

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv

from models.urban import kernels
from models.urban.network import UrbanInputError, read_net
from models.urban.scenarios import ACTIONS_MPS2, MIN_GAP_M, VEHICLE_TYPES
from models.urban.sim import ACTION_S, SPEED_MODE_CAR_FOLLOWING, SPEED_MODE_FREE, SPEED_MODE_SUMO, ScenarioFiles, Simulation

GOAL_REWARD = 1000.0  # L of Eq 4.3 (not given; "not sensitive"): a second of delay must cost more ((1 - γ) L = 10) than Eq 4.6 saves by stopping (c2 + f(v) ≤ 6)
SAFE_DIST_M = 20.0  # safe_dist of Eq 4.5-4.7 (thesis); the floor of the speed-dependent rules below
# "thesis": SAFE_DIST_M on every road; "headway": max(SAFE_DIST_M, vel x SAFE_HEADWAY_S); "stopping": max(SAFE_DIST_M,
# vel x ACTION_S + vel² / (2 x 5 m/s²)), the distance a vehicle covers while its action is held then braking at Table 4.1's max
SAFE_DIST_RULE = "thesis"
SAFE_HEADWAY_S = 2.0
MAX_BRAKE_MPS2 = 5.0
C1, C2, C3 = 0.2, 5.0, 0.4  # Eq 4.5, 4.6, 4.7
BETA1, BETA2 = 3.0, 1.0  # Eq 3.2, 3.3 (i-MARL)
MIN_FVEH_DIST_M = 1.0  # floor of fveh_dist in f(d) (Eq 4.5, 4.7; undefined at 0): one near step costs at most ~0.3 L
MAX_F_D = SAFE_DIST_M / MIN_FVEH_DIST_M  # f(d) <= 20 whatever the rule: a longer safe_dist must not make crashing cheaper than following
INTER_TIME_S = 1.5  # two vehicles reaching a junction closer in time than this are predicted to collide
# the optional safety layer (shield=True, not the thesis; shield_masks): a reservation of each junction by arrival time
SHIELD_STALL_MPS = 5.0  # a vehicle with nobody to yield to may not slow below this by its own choice (no stalls, no teleports)
SHIELD_WINDOW_S = 3.0  # two vehicles from different roads reaching a junction's centre closer in time than this conflict
SHIELD_BRAKE_MPS2 = 4.0  # braking the layer counts on: the heavy class's strongest (Table 4.1; cars have 5)
SHIELD_MEDIUM_BRAKE_MPS2 = 2.0  # a yielding vehicle may brake with Decel_M only if this stops it (heavy class's; cars 2.5)
SHIELD_ACCEL_MPS2 = 3.0  # the strongest acceleration a free vehicle may hold for the next second (Table 4.1, cars)
SHIELD_MOVE_OFF_MPS2 = 2.5  # arrival times at the centre are estimated accelerating at this from the current speed
SHIELD_REACTION_S = 0.2  # a new acceleration acts from the next sub-step
SHIELD_MARGIN_M = 5.0  # slack on the distance the layer still lets a vehicle decide freely
# a vehicle this slow inside a junction blocks it for the vehicles of its own road too; a leader this slow past the stop
# line limits the room on the exit road
SHIELD_CRAWL_MPS = 5.0
SHIELD_PATIENCE_S = 30.0  # a vehicle stopped longer than this moves up the order by the excess (no starving at a busy junction)
# room a vehicle needs on its exit road behind a slow leader to enter a junction: the longest vehicle and its standstill gap
SHIELD_EXIT_ROOM_M = max(t.length_m for t in VEHICLE_TYPES.values()) + MIN_GAP_M
# the layer also looks at the junctions after the next one on a vehicle's route: those within this distance, at most this many
SHIELD_LOOKAHEAD_M, SHIELD_LOOKAHEAD_JUNCTIONS = 250.0, 3
# actions the safety layer leaves to a vehicle (indices of Table 4.1's accelerations, strongest braking first)
SHIELD_YIELD, SHIELD_BRAKE_HARD, SHIELD_UNSTALL = np.array([1, 1, 0, 0, 0], bool), np.array([1, 0, 0, 0, 0], bool), np.array([0, 0, 0, 1, 1], bool)
POS_SCALE_M, LEADER_SCALE_M = 200.0, 200.0
STATE_DIM = {"col": 6, "ind": 4}
_CAR_MPS2, _HEAVY_MPS2 = np.array(ACTIONS_MPS2["car"]), np.array(ACTIONS_MPS2["heavy"])
_ALL_ACTIONS = np.ones(len(_CAR_MPS2), bool)
# the constants the state and reward kernels use, as the tuple they take (in the order of kernels.PARAMS)
KERNEL_PARAMS = tuple(float(dict(
    safe_dist_m=SAFE_DIST_M, safe_headway_s=SAFE_HEADWAY_S, action_s=ACTION_S, max_brake_mps2=MAX_BRAKE_MPS2, c1=C1, c2=C2, c3=C3, beta1=BETA1,
    beta2=BETA2, min_fveh_dist_m=MIN_FVEH_DIST_M, max_f_d=MAX_F_D, inter_time_s=INTER_TIME_S, pos_scale_m=POS_SCALE_M, leader_scale_m=LEADER_SCALE_M,
)[name]) for name in kernels.PARAMS)


def _rivals(junction: np.ndarray, other: np.ndarray) -> np.ndarray:
    """[n, n]: both vehicles have the same junction ahead (or are inside it; -1 = none) and `other` holds for the pair."""
    active = junction >= 0
    return (junction[:, None] == junction[None, :]) & active[:, None] & active[None, :] & other


def _stop_m(v: np.ndarray, travel_m: float | np.ndarray = 0.0) -> np.ndarray:
    """travel_m plus the distance to stop from speed v: a reaction sub-step, then SHIELD_BRAKE_MPS2 (one sum, left to right)."""
    return travel_m + v * SHIELD_REACTION_S + v**2 / (2 * SHIELD_BRAKE_MPS2)


def conflict_matrix(junction: np.ndarray, road: np.ndarray, centre_dist_m: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """conflict [n, n]: vehicle i is predicted to collide with j (Eq 4.1-4.2): both approach (or are
    inside) the same junction from different roads and reach its centre less than INTER_TIME_S apart.
    junction = -1 for vehicles with no junction ahead; road = integer code of the vehicle's road; centre_dist_m =
    inter_dist, the distance to the junction's centre (Eq 4.1)."""
    return kernels.conflict_matrix(junction, road, centre_dist_m, speed, INTER_TIME_S)


def junction_terms(junction: np.ndarray, road: np.ndarray, centre_dist_m: np.ndarray, speed: np.ndarray, incoming_lanes: np.ndarray):
    """col_term and density of every vehicle (Eq 4.2; arguments: conflict_matrix): col_term = 1 where conflict_matrix's
    row has a conflict; density (§4.2.1): "the number of vehicles that the ego vehicle is predicted to collide with",
    per incoming lane of its junction (0 with no junction ahead)."""
    return kernels.junction_terms(junction, road, centre_dist_m, speed, incoming_lanes, INTER_TIME_S)


def shield_masks(junction: np.ndarray, road: np.ndarray, centre_dist_m: np.ndarray, stop_dist_m: np.ndarray, speed: np.ndarray,
                 internal: np.ndarray, ahead_of: np.ndarray | None = None, exit_room_m: np.ndarray | None = None,
                 waited_s: np.ndarray | None = None) -> np.ndarray:
    """Allowed actions [n, 5] of n vehicles under the optional safety layer (not the thesis; an evaluation switch,
    reported separately).

    One row per vehicle and junction: the first n rows are the vehicles and the junction ahead of (or under) them; the
    rows after them are look-ahead rows, the next junctions on the route of vehicle `ahead_of[j]` (within
    SHIELD_LOOKAHEAD_M: at 30 m/s a vehicle must decide ~180 m before a junction, further than the short roads of a
    real network). junction: -1 for none; road: the road a vehicle enters the junction from (for one inside, the road
    it entered from: its followers on that road are SUMO's car following's business, unless it crawls);
    centre_dist_m: to the junction's centre (Eq 4.1); stop_dist_m: to its stop line (0 inside); internal: inside;
    exit_room_m (the first n rows; None: room everywhere): free length on the road after the junction, up to a slow vehicle
    on it (np.inf: none; negative: the slow vehicle is still inside the junction); waited_s (the first n rows): how long each vehicle has been standing (SUMO's waiting time).

    Each junction is reserved in this order: vehicles inside it, then vehicles that can no longer stop before its stop
    line (they enter whatever they do), then by arrival time at the centre, accelerating from the current speed (a
    stopped vehicle's is its move-off time sqrt(2d/a), not d / 0.1 m/s: it would otherwise never be "first"). An
    approaching vehicle yields (brakes) when a vehicle from another road with a higher place is inside the junction or reaches the centre
    less than SHIELD_WINDOW_S from it, and this second is its last chance to choose: after a second of the strongest
    acceleration it could no longer stop before the line. Farther vehicles choose freely (they are asked again next
    second). A vehicle yields if it yields at any of its junctions. Look-ahead rows come after every vehicle at that
    junction that has no junction to cross before it, unless they are committed (so, of two vehicles driving towards
    each other's next junction, each is first at its own). A vehicle first in all its conflicts at its next junction,
    or inside one, must accelerate (braking there blocks the junction for everyone); not yielding, a vehicle may not
    brake or hold below SHIELD_STALL_MPS. SUMO's car following still holds every vehicle behind its leader (a vehicle
    made to accelerate stops behind a stopped one).

    A vehicle whose exit road has no room for it (less than SHIELD_EXIT_ROOM_M) loses its place while it can still stop:
    it yields, and nobody waits for it (SUMO does not let it enter a junction it could not leave; first in the order it
    would hold every other road of the junction, and their queues the junctions behind them: a gridlock of Sc4 x2).
    A vehicle standing longer than SHIELD_PATIENCE_S counts as arriving that much earlier (a replay of Sc4: stopped 8 m
    before the line, its move-off time lost to every moving vehicle and to every stopped one nearer its line, for 120 s)."""
    rows = len(speed)
    ahead_of = np.zeros(0, int) if ahead_of is None else ahead_of
    n = rows - len(ahead_of)
    owner = np.concatenate([np.arange(n), ahead_of])
    ahead = np.arange(rows) >= n
    active = junction >= 0
    approaching = active & ~internal
    stopping_m = _stop_m(speed)
    committed = approaching & (stop_dist_m < stopping_m)  # enters the junction whatever it does now
    # after a second at the strongest acceleration it could not stop any more: the last second to decide is now
    v1 = speed + SHIELD_ACCEL_MPS2 * ACTION_S
    reach_m = _stop_m(v1, speed * ACTION_S + SHIELD_ACCEL_MPS2 * ACTION_S**2 / 2)
    deciding = approaching & (stop_dist_m <= reach_m + SHIELD_MARGIN_M)
    no_exit = np.zeros(rows, bool)
    if exit_room_m is not None:
        no_exit[:n] = (deciding & ~committed)[:n] & (exit_room_m < SHIELD_EXIT_ROOM_M)
    # arrival time at the centre accelerating at SHIELD_MOVE_OFF_MPS2, as a vehicle that goes is made to (d / v would put a
    # slow vehicle seconds after a fast one that it actually meets: a replay, both crept into the junction at once)
    arrival_s = (np.sqrt(speed**2 + 2 * SHIELD_MOVE_OFF_MPS2 * centre_dist_m) - speed) / SHIELD_MOVE_OFF_MPS2
    # place in the junction's order: rank (0 inside, 1 committed, 2 others, 3 look-ahead), then arrival time less the
    # waiting beyond patience, then list order
    rank = np.where(internal, 0, np.where(committed, 1, np.where(ahead, 3, 2)))
    credit_s = np.zeros(rows)
    if waited_s is not None:
        credit_s[:n] = np.maximum(waited_s - SHIELD_PATIENCE_S, 0.0)
    order = np.lexsort((np.arange(rows), arrival_s - credit_s, rank))
    place = np.empty(rows, int)
    place[order] = np.arange(rows)
    # vehicles of the same road are left to SUMO's car following, except behind one crawling inside the junction: it is
    # their leader only if their paths through it are the same (a replay on the real network: a follower turning the
    # other way drove into one that crawled through the junction at 0.7 m/s)
    blocking = internal & (speed < SHIELD_CRAWL_MPS)
    other_road = (road[:, None] != road[None, :]) | blocking[None, :]
    rivals = _rivals(junction, other_road) & (owner[:, None] != owner[None, :])
    close = internal[None, :] | (np.abs(arrival_s[:, None] - arrival_s[None, :]) < SHIELD_WINDOW_S)
    conflict = rivals & close & approaching[:, None] & ~no_exit[None, :]  # [i, k]: approaching i conflicts with k (inside, or close in time)
    before = place[None, :] < place[:, None]  # [i, k]: k goes before i
    behind = (conflict & before).any(axis=1)
    # per vehicle (over its rows): yields anywhere; yields hard anywhere (Decel_M only where it still stops the vehicle
    # before the line: a replay, a heavy vehicle braking at 2 m/s² from 17.5 m/s, 60 m out, entered the junction at
    # 7.5 m/s into a car crawling through it); first in all its conflicts of a row, or inside: clears
    needed_mps2 = speed**2 / (2 * np.maximum(stop_dist_m - speed * SHIELD_REACTION_S, 0.1))
    yields, hard = np.zeros(n, bool), np.zeros(n, bool)
    yields[owner[deciding & behind]] = True
    yields[no_exit[:n]] = True
    hard[owner[deciding & (behind | no_exit) & (needed_mps2 > SHIELD_MEDIUM_BRAKE_MPS2)]] = True
    clears = (internal | (approaching & conflict.any(axis=1) & ~behind & ~no_exit))[:n]  # own rows only: the first n
    v, active = speed[:n], active[:n]
    # with nobody to yield to, no braking or holding that leaves the vehicle below SHIELD_STALL_MPS (a replay: a policy that
    # braked to 0 at every second outside any conflict held a whole road at 0.7 m/s for minutes)
    mask = ~((active & ~yields)[:, None] & (_CAR_MPS2 <= 0)[None, :] & (v[:, None] + _CAR_MPS2[None, :] * ACTION_S < SHIELD_STALL_MPS))
    mask[clears] = SHIELD_UNSTALL  # accelerates, to clear the junction soon (holding a crawl blocks the others)
    mask[yields] = np.where(hard[yields, None], SHIELD_BRAKE_HARD, SHIELD_YIELD)
    return mask


def safe_dist(speed: np.ndarray, rule: str | None = None) -> np.ndarray:
    """safe_dist of Eq 4.5-4.7 (and Eq 3.3 for i-MARL) per vehicle under SAFE_DIST_RULE (or `rule`)."""
    return kernels.safe_dist(speed, _rule_code(rule), KERNEL_PARAMS)


def _rule_code(rule: str | None) -> int:
    rule = rule or SAFE_DIST_RULE
    if rule not in kernels.RULES:
        raise ValueError(f"safe_dist rule {rule!r}: expected thesis, headway or stopping")
    return kernels.RULES.index(rule)


def reward(variant: str, speed: np.ndarray, vmax: float, fveh_dist: np.ndarray, col_term: np.ndarray, rule: str | None = None) -> np.ndarray:
    """Non-terminal reward r(s, a) of every vehicle: "col" Eq 4.4-4.7 (by col_term and whether the front vehicle is
    nearer than safe_dist), "ind" Eq 3.2-3.3 with C = 1."""
    if variant not in STATE_DIM:  # the kernel takes a flag: anything but "col" would silently be "ind"
        raise ValueError(f"reward variant {variant!r}: expected one of {sorted(STATE_DIM)}")
    return kernels.reward(variant == "col", speed, vmax, fveh_dist, col_term, _rule_code(rule), KERNEL_PARAMS)


@functools.cache
def _net_geometry(net_path: str) -> tuple[dict, dict]:
    """(internal lane id -> the normal lane a vehicle on it entered the junction from, through chains of internal lanes;
    edge id -> distance (m) from its junction's centre to its start), for the safety layer."""
    net = read_net(Path(net_path), internal=True)
    via = {c.getViaLaneID(): c.getFromLane().getID() for e in net.getEdges(withInternal=True)
           for conns in e.getOutgoing().values() for c in conns if c.getViaLaneID()}
    entry = {}
    for lane in via:
        seen, origin = {lane}, via[lane]
        while origin.startswith(":") and origin in via and origin not in seen:
            seen.add(origin)
            origin = via[origin]
        entry[lane] = origin
    gap_out = {e.getID(): float(np.hypot(*np.subtract(e.getLanes()[0].getShape()[0][:2], e.getFromNode().getCoord()[:2])))
               for e in net.getEdges(withInternal=False)}
    return entry, gap_out


def entry_roads(net_path: str, index) -> np.ndarray:
    """lane code -> road code of the road a vehicle on that lane entered its junction from (a normal lane: its own road)."""
    entry = _net_geometry(net_path)[0]
    code_of_road = dict(zip(index.lane_road_id, index.lane_road.tolist()))
    out = index.lane_road.copy()
    for lane, code in index.lane_codes.items():
        if lane in entry:
            out[code] = code_of_road.get(entry[lane].rpartition("_")[0], out[code])
    return out


@dataclass(frozen=True)
class RouteTable:
    """Per route (row, as `route_rows`) and edge of its route (column), for the safety layer's look-ahead: the junction
    at the edge's end (-1 on the last edge: the goal), the road code, the position of that junction's centre along the
    route (m), the distance from the edge's stop line to it and from it to the next edge's start."""

    junction: np.ndarray
    road: np.ndarray
    centre_m: np.ndarray
    stop_to_centre_m: np.ndarray
    centre_to_exit_m: np.ndarray


def route_rows(routes: dict) -> dict:
    """route agent ('route:class') -> its route's row in per-route tables (routes: route id -> its edges, in file order)."""
    return {f"{rid}:{cls}": r for r, rid in enumerate(routes) for cls in ACTIONS_MPS2}


def route_table(net_path: str, index, routes: dict) -> RouteTable:
    """routes: route id -> its edges. Distances between junction centres: to the next edge's start plus its lane 0."""
    gap_out = _net_geometry(net_path)[1]
    shape = (len(routes), max(len(e) for e in routes.values()))
    junction, road = np.full(shape, -1), np.full(shape, -1)
    centre, stop_to_centre, centre_to_exit = np.zeros(shape), np.zeros(shape), np.zeros(shape)
    for r, edges in enumerate(routes.values()):
        codes = np.array([index.lane_codes[f"{e}_0"] for e in edges])
        junction[r, : len(edges) - 1] = index.lane_junction[codes[:-1]]
        road[r, : len(edges)] = index.lane_road[codes]
        stop_to_centre[r, : len(edges)] = index.lane_centre_m[codes] - index.lane_len[codes]
        gaps = np.array([gap_out[e] for e in edges[1:]])
        centre_to_exit[r, : len(edges) - 1] = gaps
        centre[r, : len(edges)] = np.cumsum(index.lane_centre_m[codes] + np.concatenate([[0.0], gaps]))
    return RouteTable(junction, road, centre, stop_to_centre, centre_to_exit)


@functools.lru_cache(maxsize=65536)
def route_agent(vehicle_id: str) -> str:
    """`r003.car.17` -> `r003:car` (vehicle ids are written by models.urban.scenarios); cached: asked every step."""
    route, cls, _ = vehicle_id.rsplit(".", 2)
    return f"{route}:{cls}"


class UrbanParallelEnv(ParallelEnv):
    metadata = {"name": "trafficlearn_urban_v0", "render_modes": []}

    def __init__(self, files: ScenarioFiles, variant: str = "col", sumo_seed: int = 0, record: bool = False, leader_guard: bool = True,
                 shield: bool = False):
        if variant not in STATE_DIM:
            raise ValueError(f"variant {variant!r}: expected one of {sorted(STATE_DIM)}")
        self.files, self.variant, self.sumo_seed, self.record = files, variant, sumo_seed, record
        self.shield = shield  # safety layer: infos[v]["action_mask"] = shield_masks (the env does not enforce it; the learner masks Q)
        self.action_masks: dict = {}
        self.positions = record  # x, y and acceleration are read only for recordings (the state does not use them)
        # Krauss: its safe speed is only the stopping-distance bound behind the leader (IDM's would impose IDM's acceleration law)
        self.speed_mode, self.driver_model = (SPEED_MODE_CAR_FOLLOWING, "Krauss") if leader_guard else (SPEED_MODE_FREE, "IDM")
        if not Path(files.routes).is_file():  # read here, before the Simulation would check it
            raise UrbanInputError(f"{files.routes}: scenario file not found")
        text = Path(files.routes).read_text()
        self.possible_agents = re.findall(r'<vehicle id="([^"]+)"', text)
        self.routes = {rid: edges.split() for rid, edges in re.findall(r'<route id="([^"]+)" edges="([^"]*)"', text)}
        self.route_row = route_rows(self.routes)
        self.vehicle_route = {v: self.route_row[route_agent(v)] for v in self.possible_agents}  # vehicle -> its route's row
        self.is_car = {v: ".car." in v for v in self.possible_agents}  # else heavy (Table 4.1's other accelerations)
        self.route_edges = np.array([len(edges) for edges in self.routes.values()])  # per route row
        self.vmax = files.max_speed_mps
        dim = STATE_DIM[variant]
        self._obs_space = gymnasium.spaces.Box(-1.0, np.inf, (dim,), np.float32)
        self._act_space = gymnasium.spaces.Discrete(5)
        self.agents: list = []
        self.sim: Simulation | None = None
        self.frames: list = []

    def observation_space(self, agent):
        return self._obs_space

    def action_space(self, agent):
        return self._act_space

    def reset(self, seed: int | None = None, options: dict | None = None):
        self.close()
        self.sim = Simulation(self.files, model=self.driver_model, seed=self.sumo_seed if seed is None else seed, speed_mode=self.speed_mode)
        self.sim.start()
        if self.shield:
            self._entry = entry_roads(self.files.net, self.sim.index)
            self._route_table = route_table(self.files.net, self.sim.index, self.routes)
        self.agents, self.frames, self.finished = [], [], set()
        obs = self._wait_for_agents()
        self.agents = list(obs)
        return obs, self._infos(obs)

    def step(self, actions: dict | np.ndarray | list):
        """actions: vehicle -> action (PettingZoo), or every agent's action as integers in the order of `agents`, an array
        or a list (the trainer's rollout: no dict to build and read back)."""
        sim = self.sim
        if not isinstance(actions, dict):
            actions = np.asarray(actions)
            if actions.shape != (len(self.agents),):  # a wrong length would drive the wrong vehicles, silently
                raise ValueError(f"actions: an array of shape {actions.shape}, expected ({len(self.agents)},): one per agent, in the order of env.agents")
            if actions.size and actions.dtype.kind not in "iu":  # a float would index the action table, or fail deep inside
                raise ValueError(f"actions: {actions.dtype} values, expected integer action indices")
            ids, action = self.agents, actions
        else:
            ids = [a for a in self.agents if a in actions]
            action = np.fromiter(map(actions.__getitem__, ids), int, len(ids))
        if ids:
            self._apply(ids, action, np.fromiter(map(sim.speed_of.__getitem__, ids), float, len(ids)))
        previous = self.agents
        sim.advance(ACTION_S)
        obs, rewards, goal = self._observe()
        terminated = dict.fromkeys(obs, False)
        failed = sim.new_collisions | sim.new_teleports
        for v in previous:
            if v in failed:
                rewards[v], terminated[v] = -GOAL_REWARD, True
                obs.setdefault(v, np.zeros(self._obs_space.shape, np.float32))
            elif v not in obs or v in goal:  # crossed its last junction (or arrived within the second)
                rewards[v], terminated[v] = GOAL_REWARD, True
                obs.setdefault(v, np.zeros(self._obs_space.shape, np.float32))
        self.finished |= failed
        sim.new_collisions, sim.new_teleports = set(), set()
        done = sim.done  # two libsumo calls: once per step, not per vehicle
        truncated = {v: not t for v, t in terminated.items()} if done else dict.fromkeys(terminated, False)
        self.agents = [] if done else [v for v, t in terminated.items() if not t]
        if not self.agents:  # nobody to drive right now, but vehicles may still come or be on their last road
            new = self._wait_for_agents()
            obs |= new
            terminated |= {v: False for v in new}
            done = sim.done
            truncated |= {v: done for v in new}
            self.agents = [] if done else list(new)
        return obs, rewards, terminated, truncated, self._infos(obs)

    def _infos(self, vehicles) -> dict:
        infos = {v: {"route_agent": route_agent(v)} for v in vehicles}
        if self.shield:
            for v, info in infos.items():
                info["action_mask"] = self.action_masks.get(v, _ALL_ACTIONS)
        return infos

    def _wait_for_agents(self) -> dict:
        """Simulate until some vehicle needs a decision or the episode is over (PettingZoo ends an episode
        as soon as it has no agents: without this, a gap in the traffic or the last vehicles driving their
        last road would end it early and never arrive); returns the new agents' observations."""
        sim, obs = self.sim, {}
        while not obs and not sim.done:
            sim.advance(ACTION_S)
            obs, _, goal = self._observe()
            obs = {v: o for v, o in obs.items() if v not in goal}
            self.finished |= sim.new_collisions | sim.new_teleports
            sim.new_collisions, sim.new_teleports = set(), set()
        return obs

    def _observe(self):
        """State and reward of every vehicle on the road; hands vehicles past their last junction to the fixed rule."""
        sim = self.sim
        snap = sim.snapshot(self.positions)
        if self.record:
            self.frames.append(snap)
        n = len(snap.ids)
        if n == 0:
            return {}, {}, set()
        ids = snap.ids
        state, r, last_road = self._state_reward(snap, np.fromiter(map(self.vehicle_route.__getitem__, ids), int, n))
        goal, finished = set(), self.finished
        for i in last_road.nonzero()[0].tolist():
            v = ids[i]
            if v not in finished:
                finished.add(v)
                goal.add(v)
                sim.ls.vehicle.setSpeedMode(v, SPEED_MODE_SUMO)  # SUMO's safety checks back on
                sim.ls.vehicle.setSpeed(v, self.vmax)  # max acceleration up to vel_max (§4.3.1)
        keep = slice(None)
        if len(finished.intersection(ids)) > len(goal):  # some still drive their last road (rare): they are no agents
            keep = [i for i, v in enumerate(ids) if v not in finished or v in goal]
            ids, state, r = [ids[i] for i in keep], state[keep], r[keep]
        if self.shield:
            self.action_masks = dict(zip(ids, self._masks[keep]))
        return dict(zip(ids, state)), dict(zip(ids, r.tolist())), goal

    def _apply(self, ids: list, action: np.ndarray, speed: np.ndarray) -> None:
        """Table 4.1: the chosen acceleration, held for the next second."""
        is_car = np.fromiter(map(self.is_car.__getitem__, ids), bool, len(ids))
        # speed mode 32 follows orders beyond the limits: keep 0 <= v <= vel_max over the held second
        accel = kernels.accelerations(action, is_car, speed, _CAR_MPS2, _HEAVY_MPS2, self.vmax, ACTION_S)
        self.sim.set_accelerations(ids, accel.tolist(), ACTION_S)

    def individual_state(self, snap, dist: np.ndarray) -> np.ndarray:
        """[vel / vel_max, pos / 200 m, fveh_dist / 200 m, fveh_vel / vel_max] (-1: no front vehicle), [n, 4]."""
        return kernels.individual_state(snap.speed, dist, snap.leader_dist, snap.leader_speed, self.vmax, KERNEL_PARAMS)

    def _lane_args(self, snap, route: np.ndarray) -> tuple:
        """kernels.lane_facts's arguments: each vehicle's lane, position and route (route rows) and the network's tables."""
        idx = self.sim.index
        return (snap.lane_code, snap.lane_pos, snap.route_index, route, self.route_edges, idx.lane_road, idx.lane_junction, idx.lane_internal,
                idx.lane_len, idx.lane_centre_m)

    def _state_reward(self, snap, route: np.ndarray):
        """State (Eq 4.2; i-MARL: its first 4 terms), non-terminal reward and on-its-last-road flag of every vehicle (route:
        route rows), from the network's facts of each vehicle's lane (road, junction ahead or inside, internal edge?)."""
        terms = (self.variant == "col", snap.speed, snap.leader_dist, snap.leader_speed, self.sim.index.incoming_lanes, self.vmax, _rule_code(None),
                 KERNEL_PARAMS)
        if not self.shield:  # one kernel call: every returned array costs (numba boxes it), the lane facts stay inside
            return kernels.observe(*self._lane_args(snap, route), *terms)
        road_code, junction, internal, dist, centre_dist, last_road = kernels.lane_facts(*self._lane_args(snap, route))
        self._masks = self._shield(snap, junction, road_code, internal, route, centre_dist, dist)
        col, speed, leader_dist, leader_speed, *rest = terms
        return (*kernels.state_reward(col, speed, dist, leader_dist, leader_speed, junction, road_code, centre_dist, *rest), last_road)

    def _shield(self, snap, junction: np.ndarray, road_code: np.ndarray, internal: np.ndarray, route: np.ndarray, centre_dist: np.ndarray,
                dist: np.ndarray) -> np.ndarray:
        """shield_masks of every vehicle: its own row (inside a junction: with the road it entered from), look-ahead rows
        for the next junctions of its route, the room on its exit road and how long it has stood."""
        index, table = self.sim.index, self._route_table
        if len(self._entry) < len(index.lane_road):  # lanes first seen during the episode are normal lanes: their own road
            self._entry = np.concatenate([self._entry, index.lane_road[len(self._entry):]])
        road = np.where(internal, self._entry[snap.lane_code], road_code)
        edge = np.minimum(snap.route_index[:, None] + np.arange(1, SHIELD_LOOKAHEAD_JUNCTIONS + 1), table.junction.shape[1] - 1)
        ahead_m = centre_dist[:, None] + table.centre_m[route[:, None], edge] - table.centre_m[route, snap.route_index][:, None]
        ahead_j = table.junction[route[:, None], edge]  # a clamped edge is a route's last (or padding): junction -1
        keep = (junction[:, None] >= 0) & (ahead_j >= 0) & (ahead_m <= SHIELD_LOOKAHEAD_M)
        owner, col = np.nonzero(keep)
        e = edge[owner, col]
        # room on the exit road: up to a slow leader past the stop line (getLeader looks along the route, across the junction)
        past_line = (snap.leader_dist > dist) & (snap.leader_speed < SHIELD_CRAWL_MPS)
        exit_start_m = centre_dist + table.centre_to_exit_m[route, snap.route_index]
        exit_room = np.where(past_line & ~internal, snap.leader_dist - exit_start_m, np.inf)
        # waiting counts for the first vehicle of each road only: a follower waits for its leader, not for the junction.
        # SUMO's waiting time is 0 at 0.1 m/s and above, so only the standing heads are asked
        standing = np.flatnonzero(((snap.leader_dist < 0) | (snap.leader_dist > dist)) & (snap.speed < 0.1))
        waited = np.zeros(len(snap.ids))
        waited[standing] = self.sim.waiting_s([snap.ids[i] for i in standing])
        return shield_masks(
            np.concatenate([junction, ahead_j[keep]]), np.concatenate([road, table.road[route[owner], e]]),
            np.concatenate([centre_dist, ahead_m[keep]]), np.concatenate([dist, ahead_m[keep] - table.stop_to_centre_m[route[owner], e]]),
            np.concatenate([snap.speed, snap.speed[owner]]), np.concatenate([internal, np.zeros(len(owner), bool)]), owner, exit_room, waited,
        )

    def close(self):
        if self.sim is not None:
            self.sim.close()
            self.sim = None
