"""One libsumo simulation of a scenario copy, shared by the RL environment and the SUMO baselines.

libsumo runs one simulation per process (a second `start` silently replaces the first): parallel
episodes need processes (see models.parallel). Facts measured on libsumo 1.28 that shape this file:
- crossing collisions tunnel through each other at a 1 s step: we simulate at `step_s` = 0.2 s and the
  agents act every `action_s` = 1 s; junction collisions are checked (`--collision.check-junctions`);
- `--collision.action remove` takes both vehicles out (they then also show up in the arrived list, so
  they are excluded from travel times); `--collision.mingap-factor 0` counts only real overlaps;
- `--end` is not enforced under libsumo: we loop on simulation time and stop at `max_time_s`;
- teleports (SUMO's way out of gridlock) are counted as failures.
"""

import collections
import functools
import itertools
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sumolib.geomhelper import polygonOffsetWithMinimumDistanceToPoint

from models.urban import kernels
from models.urban.network import UrbanInputError, read_net
from models.urban.scenarios import MIN_GAP_M, VEHICLE_TYPES

STEP_S = 0.2
ACTION_S = 1.0
SLACK_S = 300.0  # an episode ends at the last departure + this, whatever is still on the road has failed
TELEPORT_AFTER_S = 120.0  # SUMO teleports a vehicle stuck this long (gridlock); we count it as a failure
# TraCI speed mode bits: 0 safe speed, 1 max accel, 2 max decel, 3 right of way of approaching foes, 4 red lights,
# 5 disregard right of way inside junctions, 6 disregard speed limits. FREE: every check off (the agent's command is
# executed as is); CAR_FOLLOWING: only the safe speed behind the leader (with Krauss vTypes, the speed from which the
# vehicle can still stop behind a leader braking hard), no right of way at junctions, no speed limits (turns included)
SPEED_MODE_FREE, SPEED_MODE_CAR_FOLLOWING = 32, 1 + 32 + 64
SPEED_MODE_SUMO = 31  # SUMO's default: bits 0-4, every check on (a vehicle past its last junction, §4.3.1's fixed rule)
LEADER_LOOKAHEAD_M = 200.0  # braking from 40 m/s at 5 m/s² takes 160 m


@dataclass(frozen=True)
class ScenarioFiles:
    net: str
    routes: str
    folder: str  # holds vtypes_idm.add.xml and vtypes_krauss.add.xml
    last_depart_s: float
    max_speed_mps: float

    def vtypes(self, model: str) -> str:
        return str(Path(self.folder) / f"vtypes_{model.lower()}.add.xml")


class NetIndex:
    """Per-lane facts the state needs as arrays indexed by an integer lane code (`lane_codes`): length, distance to the
    junction centre, junction ahead, road; and the incoming lanes per junction. One dict lookup per vehicle and
    decision (lane id -> code) instead of one per fact."""

    def __init__(self, net_path: str):
        # read-only facts shared by every index of this file version (a new Simulation per episode)
        self.junction_ids, self.j_index, incoming, self.edge_junction, self.lane_length, self.centre_at = _net_facts(net_path, _stamp(net_path))
        self.incoming_lanes = incoming.copy()
        self._road_code: dict = {}  # road id -> road code
        self.lane_road_id: list = []  # lane code -> road id
        self._rows: list = []  # lane code -> (length, centre position, junction ahead, road code, internal?)
        self.lane_codes = _LaneCodes(self._add_lane)
        for lane in self.centre_at:  # every lane of the network, internal ones included; others get a code when first seen
            self.lane_codes[lane] = self._add_lane(lane, build=False)
        self._build()

    def _add_lane(self, lane: str, build: bool = True) -> int:
        road = lane.rpartition("_")[0]  # lane ids are <road>_<index>
        code = self._road_code.setdefault(road, len(self._road_code))
        self.lane_road_id.append(road)
        self._rows.append((self.lane_length.get(lane, 0.0), self.centre_at.get(lane, 0.0), self.junction_of(road), code, road.startswith(":")))
        if build:
            self._build()
        return len(self._rows) - 1

    def _build(self) -> None:
        length, centre, junction, road, internal = zip(*self._rows)
        self.lane_len, self.lane_centre_m = np.array(length, float), np.array(centre, float)
        self.lane_junction, self.lane_road, self.lane_internal = np.array(junction, int), np.array(road, int), np.array(internal, bool)

    def junction_of(self, road: str) -> int:
        """Junction a vehicle on `road` drives to; on an internal edge (':J_3') the junction it is inside."""
        if road.startswith(":"):
            return self.j_index.get(road[1:].rsplit("_", 1)[0], -1)
        return self.edge_junction.get(road, -1)


class _LaneCodes(dict):
    """lane id -> lane code; an unknown lane is added to the tables on first sight."""

    def __init__(self, add):
        super().__init__()
        self._add = add

    def __missing__(self, lane: str) -> int:
        self[lane] = code = self._add(lane)
        return code


def _stamp(path: str) -> tuple | None:
    """A file's version: inode, modification time and size (None: no such file, read_net says so); the inode catches a
    network replaced by rename within one clock tick at the same size."""
    try:
        st = Path(path).stat()
    except OSError:
        return None
    return st.st_ino, st.st_mtime_ns, st.st_size


@functools.lru_cache(maxsize=8)
def _net_facts(net_path: str, stamp: tuple | None) -> tuple:
    """What NetIndex takes from the network file, parsed once per file version (`stamp`): sumolib's two reads cost
    ~2 ms per episode on Sc1 and ~45 ms on the real network. Junction ids, junction id -> index, incoming lanes per
    junction, edge -> the junction it drives to, lane -> length, lane -> position of its junction's centre."""
    net = read_net(Path(net_path))
    nodes = list(net.getNodes())
    junction_ids = [n.getID() for n in nodes]
    j_index = {j: i for i, j in enumerate(junction_ids)}
    incoming = np.array([max(sum(e.getLaneNumber() for e in n.getIncoming()), 1) for n in nodes], float)
    edge_junction = {e.getID(): j_index[e.getToNode().getID()] for e in net.getEdges()}
    lane_length = {ln.getID(): ln.getLength() for e in net.getEdges() for ln in e.getLanes()}
    return junction_ids, j_index, incoming, edge_junction, lane_length, _centre_positions(net_path, net)


def _centre_positions(net_path: str, net) -> dict:
    """lane -> position along it (m) where a vehicle is at its junction's centre: on an approach lane its length plus
    the straight distance from its end to the centre; on a lane inside a junction the point nearest the centre."""
    out = {ln.getID(): ln.getLength() + float(np.hypot(*np.subtract(ln.getShape()[-1][:2], e.getToNode().getCoord()[:2])))
           for e in net.getEdges() for ln in e.getLanes()}
    inner = read_net(Path(net_path), internal=True)  # a separate read: with internal lanes sumolib orders the nodes differently
    for e in inner.getEdges(withInternal=True):
        junction = e.getID()[1:].rsplit("_", 1)[0]  # internal edges are ':<junction>_<n>'
        if e.getFunction() == "internal" and inner.hasNode(junction):
            centre = inner.getNode(junction).getCoord()[:2]
            out |= {ln.getID(): polygonOffsetWithMinimumDistanceToPoint(centre, ln.getShape()) for ln in e.getLanes()}
    return out


@dataclass
class Snapshot:
    """Every vehicle on the road at one time, as arrays (one entry per vehicle, order of `ids`)."""

    t: float
    ids: list
    speed: np.ndarray
    lane_pos: np.ndarray
    lane_len: np.ndarray
    lane: list
    lane_code: np.ndarray  # NetIndex lane code of `lane`: index into its lane_* tables
    route_index: np.ndarray
    x: np.ndarray
    y: np.ndarray
    accel: np.ndarray
    fuel_mgps: np.ndarray
    leader_dist: np.ndarray  # bumper-to-bumper gap (m, >= 0); -1 if no leader within LEADER_LOOKAHEAD_M
    leader_speed: np.ndarray  # -1 if no leader


@dataclass
class Tally:
    """What an episode did, for the metrics of Tables 3.2-4.9."""

    depart: dict = field(default_factory=dict)
    arrive: dict = field(default_factory=dict)
    collided: set = field(default_factory=set)
    collision_pairs: set = field(default_factory=set)
    collision_types: dict = field(default_factory=dict)  # SUMO's kind: collision (same lane), junction, frontal, ...
    teleported: set = field(default_factory=set)
    speed_sum: float = 0.0
    fuel_ml_sum: float = 0.0
    samples: int = 0
    vehicle_substeps: int = 0


class Simulation:
    """A libsumo run of one scenario copy. `speed_mode` None: SUMO's own driver model (`model`) drives —
    the IDM / Krauss baselines. Otherwise the RL env's vehicles get this speed mode on departure:
    SPEED_MODE_CAR_FOLLOWING (97, with `model` Krauss) lets SUMO cap the commanded speed at the safe speed
    behind the leader and nothing else (no rear-end collisions; junction crossings and turns are unguarded);
    SPEED_MODE_FREE (32) does exactly what it is told."""

    def __init__(self, files: ScenarioFiles, model: str = "IDM", seed: int = 0, speed_mode: int | None = None, step_s: float = STEP_S):
        self.files, self.model, self.seed, self.speed_mode, self.step_s = files, model, seed, speed_mode, step_s
        for p in (files.net, files.routes, files.vtypes(model)):
            if not Path(p).exists():
                raise UrbanInputError(f"{p}: scenario file not found")
        self.index = NetIndex(files.net)
        self.max_time_s = files.last_depart_s + SLACK_S

    def start(self) -> None:
        from models.libsumo_import import import_libsumo

        ls = import_libsumo()

        args = ["sumo", "-n", self.files.net, "-a", self.files.vtypes(self.model), "-r", self.files.routes,
                "--step-length", str(self.step_s), "--seed", str(self.seed), "--begin", "0",
                # the junction collision check as SPEC §3 prescribes it (mingap -0.5); mingap-factor 0: only real overlaps on lanes
                "--collision.action", "remove", "--collision.check-junctions", "true",
                "--collision.check-junctions.mingap", "-0.5", "--collision.mingap-factor", "0", "--time-to-teleport", str(TELEPORT_AFTER_S),
                "--no-step-log", "true", "--no-warnings", "true", "--duration-log.disable", "true"]
        try:
            ls.start(args)
        except ls.TraCIException as e:
            reason = " ".join(str(e).split())  # SUMO's message spans lines
            raise UrbanInputError(f"{self.files.routes}: SUMO cannot load the scenario ({reason})") from None
        self.ls, self.tally = ls, Tally()
        self.new_collisions: set = set()
        self.new_teleports: set = set()
        self.on_road = 0  # vehicles SUMO lists (vehicle.getIDList)
        self.in_transfer: set = set()  # vehicles being teleported now (off SUMO's list)
        self.speed_of: dict = {}  # vehicle -> its speed at the last snapshot (m/s)

    def advance(self, seconds: float) -> list:
        """Simulate `seconds` in sub-steps; returns the vehicles that departed meanwhile."""
        raw, departed = _raw(), []
        for _ in range(int(round(seconds / self.step_s))):
            raw.simulation_step(0.0)
            new, arrived, teleports = raw.simulation_getDepartedIDList(), raw.simulation_getArrivedIDList(), raw.simulation_getStartingTeleportIDList()
            collisions = raw.simulation_getCollisions()
            if new or arrived or teleports or collisions or self.in_transfer:  # most sub-steps: none of these
                self._events(new, arrived, teleports, collisions, departed)
            self.tally.vehicle_substeps += self.on_road
        return departed

    def _events(self, new: tuple, arrived: tuple, teleports: tuple, collisions: tuple, departed: list) -> None:
        """A sub-step's departures, arrivals, collisions and teleports into the tally and the count of vehicles on the road."""
        tally, raw = self.tally, _raw()
        t = raw.simulation_getTime() if new or arrived else None
        for v in new:
            if self.speed_mode is not None:
                raw.vehicle_setSpeedMode(v, self.speed_mode)
                # keep the entry speed until its first decision: uncommanded, speed mode 32 would let SUMO's
                # car-following model accelerate without its safe-speed check
                raw.vehicle_setAcceleration(v, 0.0, ACTION_S)
            tally.depart[v] = t - self.step_s
            departed.append(v)
        for col in collisions:
            pair = frozenset((col.collider, col.victim))
            if pair not in tally.collision_pairs:
                tally.collision_pairs.add(pair)
                tally.collision_types[col.type] = tally.collision_types.get(col.type, 0) + 1
                self.new_collisions |= pair
            tally.collided |= pair
        for v in teleports:
            tally.teleported.add(v)
            self.new_teleports.add(v)
        for v in arrived:
            if v not in tally.collided:
                tally.arrive[v] = t
        # vehicle.getIDCount, counted from the events instead (it builds SUMO's whole id list: µs per sub-step; a
        # vehicle being teleported is off the list, one removed after a collision is among the arrived). A teleport
        # that ends at the route's end is listed as an arrival, not as an ending teleport: that vehicle left the
        # list when its teleport started, not again when it arrives. A teleport ends only after it started: no
        # vehicle in transfer, no ending teleport
        ended = raw.simulation_getEndingTeleportIDList()
        in_transfer = self.in_transfer
        in_transfer.update(teleports)
        in_transfer.difference_update(ended)
        left = len(arrived)
        if arrived and in_transfer:
            left -= len(in_transfer.intersection(arrived))
            in_transfer.difference_update(arrived)
        self.on_road += len(new) - left - len(teleports) + len(ended)

    def snapshot(self, positions: bool = True) -> Snapshot:
        """All vehicles now, read once per decision with libsumo getters (subscriptions are recomputed by SUMO at
        every 0.2 s sub-step, and a context subscription set for the last sub-step only costs more than it saves:
        measured), one `map` per getter over all vehicles; also samples speed and fuel for the metrics.
        positions=False leaves x, y and accel as NaN (two getters fewer per vehicle: the RL state does not use them).
        The per-vehicle numbers go into one array with one `fromiter`: with a handful of vehicles, numpy's cost per call,
        not per vehicle, is what a decision pays."""
        raw, index = _raw(), self.index
        ids = list(raw.vehicle_getIDList())
        speed = list(map(raw.vehicle_getSpeed, ids))
        if speed and min(speed) < 0:  # vehicles being teleported are off the network (speed = SUMO's invalid value): left out
            ids, speed = [v for v, s in zip(ids, speed) if s >= 0], [s for s in speed if s >= 0]
        n = len(ids)
        self.speed_of = dict(zip(ids, speed))  # also for the env's next decision: its agents' speeds
        lane = list(map(raw.vehicle_getLaneID, ids))
        leader, leader_d = zip(*map(raw.vehicle_getLeader, ids, itertools.repeat(LEADER_LOOKAHEAD_M))) if n else ((), ())  # id or "", distance
        # rows: speed, position on the lane, route index, fuel rate, fuel density, lane code, leader?, leader distance, leader speed
        # (-1: none); C-level maps only: no Python frame per vehicle
        rows = np.fromiter(itertools.chain(
            speed, map(raw.vehicle_getLanePosition, ids), map(raw.vehicle_getRouteIndex, ids), map(raw.vehicle_getFuelConsumption, ids),
            map(_fuel_density, ids), map(index.lane_codes.__getitem__, lane), map(bool, leader), leader_d,
            map(self.speed_of.get, leader, itertools.repeat(-1.0))), float, 9 * n).reshape(9, n)
        code, route_index, lane_len, fuel_mlps, leader_dist, speed_sum, fuel_sum = kernels.snapshot_columns(rows, index.lane_len, MIN_GAP_M)
        if positions:
            x, y = np.array(list(map(raw.vehicle_getPosition, ids)), float).reshape(-1, 2).T
            accel = np.fromiter(map(raw.vehicle_getAcceleration, ids), float, n)
        else:
            x = y = accel = _nans(n)
        self.tally.speed_sum += speed_sum
        self.tally.fuel_ml_sum += fuel_sum
        self.tally.samples += n
        return Snapshot(t=raw.simulation_getTime(), ids=ids, speed=rows[0], lane_pos=rows[1], lane_len=lane_len, lane=lane, lane_code=code,
                        route_index=route_index, x=x, y=y, accel=accel, fuel_mgps=rows[3], leader_dist=leader_dist, leader_speed=rows[8])

    def set_accelerations(self, ids: list, accel_mps2: list, seconds: float) -> None:
        """Each vehicle's acceleration, held for `seconds` (libsumo's C setter: its Python wrapper adds a frame per vehicle;
        mapped and drained in C: no bytecode per vehicle)."""
        collections.deque(map(_raw().vehicle_setAcceleration, ids, accel_mps2, itertools.repeat(seconds)), maxlen=0)

    def waiting_s(self, ids: list) -> np.ndarray:
        """SUMO's waiting time of these vehicles (s spent below 0.1 m/s since they last moved), with its C getter."""
        return np.fromiter(map(_raw().vehicle_getWaitingTime, ids), float, len(ids))

    @property
    def time(self) -> float:
        return self.ls.simulation.getTime()

    @property
    def done(self) -> bool:
        raw = _raw()
        return raw.simulation_getMinExpectedNumber() == 0 or raw.simulation_getTime() >= self.max_time_s

    def close(self) -> None:
        self.ls.close()

    def metrics(self, n_vehicles: int) -> dict:
        """Average travel time of the vehicles that reached their destination, average speed and fuel over
        1 s samples of all vehicles, distinct colliding pairs, teleports; success = no collision, no
        teleport and every vehicle arrived."""
        t = self.tally
        tt = [t.arrive[v] - t.depart[v] for v in t.arrive]
        return {
            "avg_travel_time_s": float(np.mean(tt)) if tt else float("nan"),
            "avg_speed_mps": t.speed_sum / t.samples if t.samples else float("nan"),
            "avg_fuel_mlps": t.fuel_ml_sum / t.samples if t.samples else float("nan"),
            "collisions": len(t.collision_pairs),
            "teleports": len(t.teleported),
            "arrived": len(t.arrive),
            "success": not t.collision_pairs and not t.teleported and len(t.arrive) == n_vehicles,
        }


@functools.cache
def _raw():
    """libsumo's C functions (`vehicle_getSpeed`, ...) without its Python wrappers (`libsumo.vehicle.getSpeed` calls
    them through one more Python frame): the getters, setters and steps the env calls for every vehicle and sub-step,
    a third of the env's Python time per decision (measured). Same functions, same values."""
    from libsumo import _libsumo

    return _libsumo


@functools.lru_cache(maxsize=1024)
def _nans(n: int) -> np.ndarray:
    """n NaNs, read-only: one array per length for every snapshot without positions (np.full was µs per decision)."""
    out = np.full(n, np.nan)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=65536)
def _fuel_density(vehicle_id: str) -> float:
    """mg/ml of the vehicle's fuel: ids are `<route>.<agent class>.<n>`; the heavy class burns diesel either way."""
    return VEHICLE_TYPES["car" if vehicle_id.split(".")[-2] == "car" else "bus"].fuel_density_mg_per_ml


def run_sumo_model(files: ScenarioFiles, n_vehicles: int, model: str, seed: int, record: bool = False) -> tuple[dict, list, set, set]:
    """A SUMO baseline (IDM or Krauss) on the same unsignalized network and demand; optional 1 s trajectories
    -> (metrics, frames, vehicles that collided, vehicles SUMO teleported)."""
    sim = Simulation(files, model=model, seed=seed)
    sim.start()
    frames = []
    try:
        while not sim.done:
            sim.advance(ACTION_S)
            snap = sim.snapshot()
            if record:
                frames.append(snap)
        return sim.metrics(n_vehicles), frames, set(sim.tally.collided), set(sim.tally.teleported)
    finally:
        sim.close()
