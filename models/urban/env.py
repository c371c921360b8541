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
"headway" and "stopping" make it grow with speed (measured: no fewer collisions after the demo budget, see
docs/urban.md).

Car-following safety (leader_guard=True, the default): SUMO caps each agent vehicle's commanded speed at the
safe speed behind its leader (speed mode 97 with Krauss vehicle types: the speed from which it can still stop
behind a leader braking hard), and nothing else: no right of way at the junctions, no speed limits, the agent's
acceleration otherwise executed as is. The thesis's agents learn to cross unsignalized junctions; car following is
left to the simulator as for its IDM baseline, which "shares the same safety settings as the proposed method (i.e.,
unsignalized intersections, no right-way rule, and so on)" (§4.3.1; docs/urban.md). leader_guard=False: every
SUMO check off (speed mode 32), rear-end collisions possible.
"""

import functools
import re
from pathlib import Path

import gymnasium
import numpy as np
from pettingzoo import ParallelEnv

from models.urban.scenarios import ACTIONS_MPS2
from models.urban.sim import ACTION_S, SPEED_MODE_CAR_FOLLOWING, SPEED_MODE_FREE, ScenarioFiles, Simulation

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
SHIELD_STALL_MPS = 1.0  # the optional safety layer (shield=True) forbids braking or holding below this speed with no predicted conflict
# actions the safety layer leaves to a vehicle (indices of Table 4.1's accelerations, strongest braking first)
SHIELD_YIELD, SHIELD_GO, SHIELD_UNSTALL = np.array([1, 1, 0, 0, 0], bool), np.array([0, 0, 1, 1, 1], bool), np.array([0, 0, 0, 1, 1], bool)
POS_SCALE_M, LEADER_SCALE_M = 200.0, 200.0
STATE_DIM = {"col": 6, "ind": 4}
_CAR_MPS2, _HEAVY_MPS2 = np.array(ACTIONS_MPS2["car"]), np.array(ACTIONS_MPS2["heavy"])


def conflict_matrix(junction: np.ndarray, road: np.ndarray, centre_dist_m: np.ndarray, speed: np.ndarray):
    """(inter_time [n], conflict [n, n]): vehicle i is predicted to collide with j (Eq 4.1-4.2): both approach (or are
    inside) the same junction from different roads and reach its centre less than INTER_TIME_S apart.
    junction = -1 for vehicles with no junction ahead; road = integer code of the vehicle's road; centre_dist_m =
    inter_dist, the distance to the junction's centre (Eq 4.1)."""
    inter_time = centre_dist_m / np.maximum(speed, 0.1)
    active = junction >= 0
    same_junction = (junction[:, None] == junction[None, :]) & active[:, None] & active[None, :]
    other_road = road[:, None] != road[None, :]
    close_in_time = np.abs(inter_time[:, None] - inter_time[None, :]) < INTER_TIME_S
    return inter_time, same_junction & other_road & close_in_time


def junction_terms(junction: np.ndarray, road: np.ndarray, centre_dist_m: np.ndarray, speed: np.ndarray, incoming_lanes: np.ndarray):
    """col_term and density of every vehicle (Eq 4.2), vectorised over all vehicles and junctions (arguments: conflict_matrix)."""
    active = junction >= 0
    conflicts = conflict_matrix(junction, road, centre_dist_m, speed)[1].sum(axis=1)
    # density (§4.2.1): "the number of vehicles that the ego vehicle is predicted to collide with", per incoming lane
    density = np.where(active, conflicts / incoming_lanes[np.maximum(junction, 0)], 0.0)
    return (conflicts > 0).astype(float), density


def shield_masks(junction: np.ndarray, road: np.ndarray, centre_dist_m: np.ndarray, speed: np.ndarray) -> np.ndarray:
    """Allowed actions [n, 5] under the optional safety layer (not the thesis; an evaluation switch, reported separately):
    of two vehicles predicted to collide (conflict_matrix) the one that reaches the junction's centre first goes on (no
    braking) and the other one brakes (first come, first served; ties: the earlier vehicle in the list goes first); a
    vehicle below SHIELD_STALL_MPS with no predicted conflict must accelerate (SUMO's car-following safety still holds it
    behind a leader). Everything else is the policy's choice."""
    inter_time, conflict = conflict_matrix(junction, road, centre_dist_m, speed)
    n = len(speed)
    earlier = (inter_time[None, :] < inter_time[:, None]) | ((inter_time[None, :] == inter_time[:, None]) & (np.arange(n)[None, :] < np.arange(n)[:, None]))
    yields = (conflict & earlier).any(axis=1)
    in_conflict = conflict.any(axis=1)
    mask = np.ones((n, len(SHIELD_YIELD)), bool)
    mask[yields] = SHIELD_YIELD
    mask[in_conflict & ~yields] = SHIELD_GO
    mask[~in_conflict & (speed < SHIELD_STALL_MPS) & (junction >= 0)] = SHIELD_UNSTALL
    return mask


def safe_dist(speed: np.ndarray, rule: str | None = None) -> np.ndarray:
    """safe_dist of Eq 4.5-4.7 (and Eq 3.3 for i-MARL) per vehicle under SAFE_DIST_RULE (or `rule`)."""
    rule = rule or SAFE_DIST_RULE
    if rule == "thesis":
        return np.full(np.shape(speed), SAFE_DIST_M)
    if rule == "headway":
        return np.maximum(SAFE_DIST_M, speed * SAFE_HEADWAY_S)
    if rule == "stopping":
        return np.maximum(SAFE_DIST_M, speed * ACTION_S + speed**2 / (2 * MAX_BRAKE_MPS2))
    raise ValueError(f"safe_dist rule {rule!r}: expected thesis, headway or stopping")


def reward(variant: str, speed: np.ndarray, vmax: float, fveh_dist: np.ndarray, col_term: np.ndarray, rule: str | None = None) -> np.ndarray:
    """Non-terminal reward r(s, a), vectorised."""
    fv = speed / vmax
    sd = safe_dist(speed, rule)
    near = (fveh_dist >= 0) & (fveh_dist < sd)
    if variant == "ind":
        return np.where(near, -(BETA2 + fv) * (sd - fveh_dist), BETA1 * fv)  # Eq 3.2, 3.3 with C = 1
    fd = np.minimum(sd / np.maximum(np.minimum(fveh_dist, sd), MIN_FVEH_DIST_M), MAX_F_D)
    return np.where(
        col_term > 0,
        np.where(near, -(C3 + fv) * fd, -(C2 + fv)),  # Eq 4.7, 4.6
        np.where(near, -(C1 + fv) * fd, fv),  # Eq 4.5, 4.4
    )


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
        text = Path(files.routes).read_text()
        self.possible_agents = re.findall(r'<vehicle id="([^"]+)"', text)
        self.route_edges = {  # route agent -> edges of its route
            f"{rid}:{cls}": len(edges.split()) for rid, edges in re.findall(r'<route id="([^"]+)" edges="([^"]*)"', text) for cls in ACTIONS_MPS2
        }
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
        self.agents, self.frames, self.finished = [], [], set()
        obs = self._wait_for_agents()
        self.agents = list(obs)
        return obs, self._infos(obs)

    def step(self, actions: dict):
        sim = self.sim
        ids = [a for a in self.agents if a in actions]
        if ids:
            snap = self._last
            row = {v: i for i, v in enumerate(snap.ids)}
            self._apply(ids, np.array([int(actions[v]) for v in ids]), snap.speed[[row[v] for v in ids]])
        previous = self.agents
        sim.advance(ACTION_S)
        obs, rewards, goal = self._observe()
        terminated = {}
        for v in previous:
            if v in sim.new_collisions or v in sim.new_teleports:
                rewards[v], terminated[v] = -GOAL_REWARD, True
                obs.setdefault(v, np.zeros(self._obs_space.shape, np.float32))
            elif v not in obs or v in goal:  # crossed its last junction (or arrived within the second)
                rewards[v], terminated[v] = GOAL_REWARD, True
                obs.setdefault(v, np.zeros(self._obs_space.shape, np.float32))
        self.finished |= sim.new_collisions | sim.new_teleports
        sim.new_collisions, sim.new_teleports = set(), set()
        terminated = {v: terminated.get(v, False) for v in obs}
        done = sim.done  # two libsumo calls: once per step, not per vehicle
        truncated = {v: done and not terminated[v] for v in obs}
        self.agents = [v for v in obs if not terminated[v] and not truncated[v]]
        if not self.agents:  # nobody to drive right now, but vehicles may still come or be on their last road
            new = self._wait_for_agents()
            obs |= new
            terminated |= {v: False for v in new}
            done = sim.done
            truncated |= {v: done for v in new}
            self.agents = [] if done else list(new)
        return obs, rewards, terminated, truncated, self._infos(obs)

    def _infos(self, vehicles) -> dict:
        if self.shield:
            return {v: {"route_agent": route_agent(v), "action_mask": self.action_masks.get(v, SHIELD_GO | SHIELD_YIELD)} for v in vehicles}
        return {v: {"route_agent": route_agent(v)} for v in vehicles}

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
        sim, idx = self.sim, self.sim.index
        snap = sim.snapshot(self.positions)
        self._last = snap
        if self.record:
            self.frames.append(snap)
        n = len(snap.ids)
        if n == 0:
            return {}, {}, set()
        # the network's facts of each vehicle's lane: road, junction ahead (or inside), internal edge?
        road_code, junction, internal = idx.lane_road[snap.lane_code], idx.lane_junction[snap.lane_code], idx.lane_internal[snap.lane_code]
        n_edges = np.array([self.route_edges[route_agent(v)] for v in snap.ids])
        last_road = (snap.route_index >= n_edges - 1) & ~internal
        junction[last_road] = -1
        dist = np.where(internal, 0.0, np.maximum(snap.lane_len - snap.lane_pos, 0.0))
        state, r = self._state_reward(snap, junction, road_code, dist)
        goal = set()
        for i in np.flatnonzero(last_road):
            v = snap.ids[i]
            if v not in self.finished:
                self.finished.add(v)
                goal.add(v)
                sim.ls.vehicle.setSpeedMode(v, 31)  # SUMO's safety checks back on
                sim.ls.vehicle.setSpeed(v, self.vmax)  # max acceleration up to vel_max (§4.3.1)
        keep = [i for i, v in enumerate(snap.ids) if v not in self.finished or v in goal]
        obs = {snap.ids[i]: state[i] for i in keep}
        if self.shield:
            self.action_masks = {snap.ids[i]: self._masks[i] for i in keep}
        rewards = {snap.ids[i]: float(r[i]) for i in keep}
        return obs, rewards, goal

    def _apply(self, ids: list, action: np.ndarray, speed: np.ndarray) -> None:
        """Table 4.1: the chosen acceleration, held for the next second."""
        is_car = np.array([".car." in v for v in ids])
        accel = np.where(is_car, _CAR_MPS2[action], _HEAVY_MPS2[action])
        # speed mode 32 follows orders beyond the limits: keep 0 <= v <= vel_max over the held second
        accel = np.clip(accel, -speed / ACTION_S, (self.vmax - speed) / ACTION_S)
        set_acceleration = self.sim.ls.vehicle.setAcceleration
        for v, a in zip(ids, accel.tolist()):
            set_acceleration(v, a, ACTION_S)

    def individual_state(self, snap, dist: np.ndarray) -> np.ndarray:
        """[vel / vel_max, pos / 200 m, fveh_dist / 200 m, fveh_vel / vel_max] (-1: no front vehicle), [n, 4]."""
        # the four terms in one array, so one division and one `where` for all (vel and pos are never negative:
        # only a missing front vehicle's -1 is kept as -1)
        terms = np.array([snap.speed, dist, snap.leader_dist, snap.leader_speed])
        scale = np.array([[self.vmax], [POS_SCALE_M], [LEADER_SCALE_M], [self.vmax]])
        return np.where(terms >= 0, terms / scale, -1.0).T

    def _state_reward(self, snap, junction: np.ndarray, road_code: np.ndarray, dist: np.ndarray):
        """State (Eq 4.2; i-MARL: its first 4 terms) and non-terminal reward of every vehicle."""
        index = self.sim.index
        centre_dist = index.centre_dist(snap.lane_code, snap.lane_pos)
        col_term, density = junction_terms(junction, road_code, centre_dist, snap.speed, index.incoming_lanes)
        if self.shield:
            self._masks = shield_masks(junction, road_code, centre_dist, snap.speed)
        state = np.empty((len(dist), STATE_DIM[self.variant]), np.float32)  # filled column-wise: no stacking, one cast
        state[:, :4] = self.individual_state(snap, dist)
        if state.shape[1] == 6:
            state[:, 4], state[:, 5] = col_term, density
        return state, reward(self.variant, snap.speed, self.vmax, snap.leader_dist, col_term)

    def close(self):
        if self.sim is not None:
            self.sim.close()
            self.sim = None
