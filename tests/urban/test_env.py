"""The environment over real libsumo: collisions detected, Eq 4.2 terms, determinism, PettingZoo API."""

import hashlib

import numpy as np
import pytest

from models.urban import kernels
from models.urban.col_marl import EpisodeJob, RouteAgentsQ, numpy_params, run_episode
from models.urban.env import GOAL_REWARD, UrbanParallelEnv, junction_terms, reward, safe_dist
from models.urban.network import UrbanInputError, read_net
from models.urban.sim import LEADER_LOOKAHEAD_M, SPEED_MODE_CAR_FOLLOWING, STEP_S, NetIndex, ScenarioFiles, Simulation, run_sumo_model

from models.urban.scenarios import MIN_GAP_M
from urban_fixtures import crossing_copy, hand_copy, make_copy

HOLD = 2  # index of the zero acceleration in Table 4.1


def test_forced_crossing_is_a_collision(tmp_path, sc1_net):
    env = UrbanParallelEnv(crossing_copy(tmp_path / "cross", sc1_net))
    obs, infos = env.reset(seed=0)
    assert set(obs) == {"r000.car.0", "r001.car.1"} and infos["r000.car.0"]["route_agent"] == "r000:car"
    assert all(o[4] == 1.0 for o in obs.values())  # both predicted to collide: same inter_time, other roads
    penalties = {}
    while env.agents:
        obs, rewards, terminated, truncated, _ = env.step({a: HOLD for a in env.agents})
        penalties.update({v: r for v, r in rewards.items() if terminated.get(v)})
    tally = env.sim.tally
    env.close()
    assert len(tally.collision_pairs) == 1 and tally.collision_types == {"junction": 1}
    assert penalties == {"r000.car.0": -GOAL_REWARD, "r001.car.1": -GOAL_REWARD}


def test_vehicles_on_the_road_are_counted_from_the_events(tmp_path, sc1_net):
    # the vehicle-steps of a run (the bench's figure) add up SUMO's vehicle count after every sub-step, kept from the
    # departures, arrivals (removed colliders among them) and teleports rather than asked of getIDCount each time
    collided = []
    for files, speed_mode in [(crossing_copy(tmp_path / "cross", sc1_net), SPEED_MODE_CAR_FOLLOWING),
                              (make_copy(tmp_path / "c", sc1_net, 20, 40.0)[0], None)]:
        sim = Simulation(files, model="Krauss", seed=0, speed_mode=speed_mode)
        sim.start()
        counted = 0
        while not sim.done:
            sim.advance(STEP_S)
            assert sim.on_road == sim.ls.vehicle.getIDCount()
            counted += sim.on_road
        assert sim.tally.vehicle_substeps == counted > 0
        collided.append(len(sim.tally.collided))
        sim.close()
    assert collided == [2, 0]  # the forced crossing: both vehicles removed (and listed as arrived)


def test_a_teleport_to_the_route_end_is_counted_once(tmp_path, sc1_net):
    # a car stopped by order is teleported twice after TELEPORT_AFTER_S: onto its last road (the teleport starts and ends
    # in one sub-step), then past its route's end: that teleport is listed as an arrival, never as an ending teleport
    files = hand_copy(tmp_path / "stuck", sc1_net, '  <route id="r000" edges="left0A0 A0right0"/>\n'
                      '  <vehicle id="r000.car.0" type="car" route="r000" depart="0" departSpeed="10" departPos="base"/>\n')
    sim = Simulation(files, model="Krauss", seed=0, speed_mode=SPEED_MODE_CAR_FOLLOWING)
    sim.start()
    counts = []
    while not sim.done:
        for v in sim.advance(STEP_S):
            sim.ls.vehicle.setSpeed(v, 0.0)
        counts.append((sim.on_road, sim.ls.vehicle.getIDCount()))
    sim.close()
    assert len(sim.tally.teleported) == 1 and counts[-1] == (0, 0) and all(a == b for a, b in counts)


def test_a_teleport_that_ends_in_a_quiet_sub_step_is_counted(monkeypatch):
    # a teleport ends (the vehicle back on SUMO's list) only sub-steps after it started when the next road is full: that
    # sub-step may have no departure, arrival, collision or new teleport, and the count must still take the vehicle back.
    # SUMO's event lists scripted (the jam is hard to make on demand): a, b depart; a's teleport starts; nothing; it ends
    from models.urban import sim as sim_module
    from models.urban.sim import Tally

    script = [{"departed": ("a", "b")}, {"starting": ("a",)}, {}, {"ending": ("a",)}, {}]
    now = []

    class Raw:
        def simulation_step(self, t):
            now.append(script[len(now)])

        def simulation_getTime(self):
            return len(now) * STEP_S

        def __getattr__(self, name):  # the event getters: this sub-step's list
            key = {"simulation_getDepartedIDList": "departed", "simulation_getArrivedIDList": "arrived",
                   "simulation_getStartingTeleportIDList": "starting", "simulation_getEndingTeleportIDList": "ending",
                   "simulation_getCollisions": "collisions"}[name]
            return lambda: now[-1].get(key, ())

    monkeypatch.setattr(sim_module, "_raw", Raw)
    sim = object.__new__(Simulation)  # no SUMO: what advance reads
    sim.step_s, sim.speed_mode, sim.tally, sim.on_road, sim.in_transfer = STEP_S, None, Tally(), 0, set()
    sim.new_collisions, sim.new_teleports = set(), set()
    counts = []
    for _ in script:
        sim.advance(STEP_S)
        counts.append(sim.on_road)
    assert counts == [2, 1, 1, 2, 2] and sim.tally.vehicle_substeps == 8 and not sim.in_transfer and sim.tally.teleported == {"a"}


def test_sumo_idm_obeys_right_before_left_on_the_same_crossing(tmp_path, sc1_net):
    metrics, *_ = run_sumo_model(crossing_copy(tmp_path / "cross", sc1_net), 2, "IDM", 0)
    assert metrics["collisions"] == 0 and metrics["arrived"] == 2 and metrics["success"]


def test_junction_terms_and_reward():
    # vehicles 0 and 1 reach junction 0 from different roads 0.5 s apart; 2 follows 0 on its road; 3 is on its last road
    junction = np.array([0, 0, 0, -1])
    road = np.array([0, 1, 0, 2])
    col, density = junction_terms(junction, road, np.array([100.0, 110.0, 130.0, 50.0]), np.array([10.0, 10.0, 10.0, 10.0]), np.array([4.0]))
    assert col.tolist() == [1.0, 1.0, 0.0, 0.0]
    assert density.tolist() == [0.25, 0.25, 0.0, 0.0]  # vehicles it is predicted to collide with, per incoming lane (§4.2.1)
    r = reward("col", np.array([20.0, 20.0, 20.0, 20.0]), 40.0, np.array([-1.0, 10.0, -1.0, 10.0]), np.array([0.0, 0.0, 1.0, 1.0]))
    assert r == pytest.approx([0.5, -(0.2 + 0.5) * 2.0, -(5.0 + 0.5), -(0.4 + 0.5) * 2.0])  # Eq 4.4, 4.5, 4.6, 4.7
    assert reward("ind", np.array([20.0]), 40.0, np.array([10.0]), np.array([1.0])) == pytest.approx([-(1.0 + 0.5) * 10.0])
    with pytest.raises(ValueError, match=r"^reward variant 'ch3': expected one of \['col', 'ind'\]$"):
        reward("ch3", np.array([20.0]), 40.0, np.array([10.0]), np.array([1.0]))



def _centre_dist(index, lane: str, pos: list) -> np.ndarray:
    """inter_dist as the env reads it (kernels.lane_facts) for vehicles at these positions on `lane`, far from their goal."""
    n = len(pos)
    codes, zeros = np.full(n, index.lane_codes[lane]), np.zeros(n, np.int64)
    return kernels.lane_facts(codes, np.array(pos), zeros, zeros, np.array([99]), index.lane_road, index.lane_junction, index.lane_internal,
                              index.lane_len, index.lane_centre_m)[4]


def test_inter_dist_is_the_distance_to_the_junction_centre(sc1_net):
    index = NetIndex(str(sc1_net))
    centre = np.array(read_net(sc1_net).getNode("A0").getCoord())
    end = np.array(read_net(sc1_net).getLane("left0A0_0").getShape()[-1])
    length = index.lane_length["left0A0_0"]
    # on the approach: the rest of the lane plus the lane end's distance to the centre (Eq 4.1), not the lane end
    approach = _centre_dist(index, "left0A0_0", [length - 50.0, length])
    np.testing.assert_allclose(approach, [50.0 + np.linalg.norm(end - centre), np.linalg.norm(end - centre)], rtol=1e-6)
    assert 5.0 < approach[1] < 10.0
    # inside the junction, straight on (:A0_10 from the left to the right): the centre is halfway; 0 once past it
    inside = _centre_dist(index, ":A0_10_0", [0.0, 7.2, 12.0])
    np.testing.assert_allclose(inside, [7.2, 0.0, 0.0], atol=0.05)


def test_lane_table_holds_each_lanes_road_junction_and_length(sc1_net):
    # what the env reads per vehicle and decision, one row per lane found by its integer code
    index, net = NetIndex(str(sc1_net)), read_net(sc1_net)
    a0 = index.j_index["A0"]
    for lane, road, junction, internal, length in [
        ("left0A0_0", "left0A0", a0, False, net.getLane("left0A0_0").getLength()),  # approach: the junction ahead
        (":A0_10_0", ":A0_10", a0, True, 0.0),  # inside: the junction it is in (its length is not used: pos = 0)
        ("A0right0_0", "A0right0", index.j_index["right0"], False, net.getLane("A0right0_0").getLength()),  # exit: the dead end
    ]:
        c = index.lane_codes[lane]
        assert (index.lane_road_id[c], index.lane_junction[c], index.lane_internal[c], index.lane_len[c]) == (road, junction, internal, length)
    assert index.lane_road[index.lane_codes["left0A0_0"]] != index.lane_road[index.lane_codes[":A0_10_0"]]
    # a lane the network file does not have gets its row on first sight, not a KeyError
    n = len(index.lane_len)
    c = index.lane_codes["nowhere_0"]
    assert c == n and len(index.lane_junction) == n + 1 and index.lane_junction[c] == -1 and index.lane_road_id[c] == "nowhere"


def test_the_network_file_is_parsed_once_per_version(tmp_path, sc1_net, monkeypatch):
    # a Simulation per episode builds a NetIndex: sumolib's parse (~45 ms on the real network) only for a new file version
    import shutil

    from models.urban import sim as sim_module

    net = tmp_path / "n.net.xml"
    shutil.copy(sc1_net, net)
    reads = []
    monkeypatch.setattr(sim_module, "read_net", lambda path, internal=False: reads.append(path) or read_net(path, internal))
    first, second = NetIndex(str(net)), NetIndex(str(net))
    assert len(reads) == 2  # the network and its internal lanes, once
    assert first.lane_codes == second.lane_codes and np.array_equal(first.lane_len, second.lane_len)
    second.lane_codes["nowhere_0"]  # an index's own lanes stay its own
    assert "nowhere_0" not in first.lane_codes and "nowhere_0" not in NetIndex(str(net)).lane_codes
    net.write_text(net.read_text().replace("<net ", "<net  ", 1))  # a new version (size): parsed again
    NetIndex(str(net))
    assert len(reads) == 4
    with pytest.raises(UrbanInputError, match="network file not found"):
        NetIndex(str(tmp_path / "missing.net.xml"))


def test_speed_dependent_safe_dist():
    v = np.array([0.0, 10.0, 30.0])
    assert safe_dist(v).tolist() == [20.0, 20.0, 20.0]  # the thesis's constant is the default
    assert safe_dist(v, "headway").tolist() == [20.0, 20.0, 60.0]  # 2 s headway, never below 20 m
    assert safe_dist(v, "stopping").tolist() == [20.0, 20.0, 30.0 + 90.0]  # 1 s held action + braking at 5 m/s²
    # 40 m behind a leader at 30 m/s: far for the thesis, near under the stopping rule; f(d) stays capped at 20
    far, near = (reward("col", np.array([30.0]), 40.0, np.array([40.0]), np.array([0.0]), rule) for rule in ("thesis", "stopping"))
    assert far == pytest.approx([0.75]) and near == pytest.approx([-(0.2 + 0.75) * 3.0])
    assert reward("col", np.array([30.0]), 40.0, np.array([0.5]), np.array([0.0]), "stopping") == pytest.approx([-(0.2 + 0.75) * 20.0])
    with pytest.raises(ValueError, match="safe_dist rule"):
        safe_dist(v, "nope")

def test_same_seed_same_episode(tmp_path, sc1_net):
    files, routes = make_copy(tmp_path / "c", sc1_net, 20, 80.0)
    agents = [f"{r['route_id']}:{c}" for r in routes for c in ("car", "heavy")]
    import torch

    params = numpy_params(RouteAgentsQ(len(agents), 6, torch.Generator().manual_seed(0)))
    a, b = (run_episode(EpisodeJob(files, "col", agents, params, 0.5, 11, 20)) for _ in range(2))
    assert a.metrics == b.metrics
    assert all(np.array_equal(a.transitions[k], b.transitions[k]) for k in a.transitions)
    c = run_episode(EpisodeJob(files, "col", agents, params, 0.5, 12, 20))
    assert not np.array_equal(a.transitions["action"], c.transitions["action"])


def test_snapshot_reads_what_the_getters_say(tmp_path, sc1_net):
    # each vehicle's road follows from its lane code (the lane table) and x, y and accel are skipped unless asked for
    sim = Simulation(make_copy(tmp_path / "c", sc1_net, 20, 40.0)[0], model="Krauss", seed=0)
    sim.start()
    try:
        seen_internal = False
        for _ in range(30):
            sim.advance(1.0)
            full, light = sim.snapshot(), sim.snapshot(positions=False)
            veh = sim.ls.vehicle
            road = [sim.index.lane_road_id[c] for c in full.lane_code]
            assert road == [veh.getRoadID(v) for v in full.ids]
            assert full.lane_code.tolist() == [sim.index.lane_codes[veh.getLaneID(v)] for v in full.ids]
            assert full.speed.tolist() == [veh.getSpeed(v) for v in full.ids]
            leaders = [veh.getLeader(v, LEADER_LOOKAHEAD_M) for v in full.ids]  # None: no leader
            assert full.leader_dist.tolist() == [max(ld[1] + MIN_GAP_M, 0.0) if ld else -1.0 for ld in leaders]
            assert full.x.tolist() == [veh.getPosition(v)[0] for v in full.ids]
            assert full.accel.tolist() == [veh.getAcceleration(v) for v in full.ids]
            seen_internal |= any(r.startswith(":") for r in road)
            for k in ("speed", "lane_pos", "lane_len", "route_index", "leader_dist", "leader_speed", "fuel_mgps"):
                assert np.array_equal(getattr(full, k), getattr(light, k)), k
            assert full.ids == light.ids and full.lane == light.lane and np.array_equal(full.lane_code, light.lane_code)
            assert np.isnan(light.x).all() and np.isnan(light.accel).all()
        assert seen_internal  # a vehicle inside the junction: its road is the internal edge
    finally:
        sim.close()


def _scripted_episode(files: ScenarioFiles, seed: int, leader_guard: bool = True) -> tuple:
    """col-MARL's env under a fixed rule (full acceleration unless a collision is predicted, then full braking; 30 %
    random actions): a digest of every observation, reward and end flag, the steps, the sum of the rewards, the
    collisions and arrivals. Exact comparisons only in the rule, so the same on any machine."""
    env = UrbanParallelEnv(files, "col", leader_guard=leader_guard)
    rng = np.random.default_rng(seed)
    digest, steps, reward_sum = hashlib.sha256(), 0, 0.0
    obs, _ = env.reset(seed=seed)
    while env.agents:
        ids = sorted(env.agents)
        actions = np.where(rng.random(len(ids)) < 0.3, rng.integers(0, 5, len(ids)), [0 if obs[v][4] > 0 else 4 for v in ids])
        obs, rewards, terminated, truncated, _ = env.step(dict(zip(ids, actions.tolist())))
        for v in sorted(obs):
            digest.update(f"{v} {rewards.get(v)!r} {terminated[v]} {truncated[v]}".encode() + obs[v].tobytes())
        steps += 1
        reward_sum += sum(rewards.values())
    metrics = env.sim.metrics(20)
    env.close()
    return digest.hexdigest()[:16], steps, round(reward_sum, 6), metrics["collisions"], metrics["arrived"]


def test_episodes_are_the_ones_recorded_before_the_faster_state_read(tmp_path, sc1_net):
    # recorded with the code of commit 9ad9744, before the env's speed work of issue 4 (lane table, libsumo's C
    # getters, column-wise state): that work must not change an episode by a bit. A deliberate change of the
    # dynamics, the state or the reward changes these values: then re-record them (run this episode, print the tuple)
    files, _ = make_copy(tmp_path / "c", sc1_net, 20, 40.0)
    assert _scripted_episode(files, 7) == ("7e5b7b99176ccab8", 101, 10584.563898, 2, 16)
    assert _scripted_episode(files, 7, leader_guard=False) == ("338300890ce309e7", 53, -210.262798, 5, 10)


def test_actions_as_an_array_in_the_agents_order_are_the_dict(tmp_path, sc1_net):
    # the trainer's rollout hands step its actions as an array (no dict per decision): the same episode as the dicts
    # (one env at a time: libsumo runs one simulation per process)
    files, _ = make_copy(tmp_path / "c", sc1_net, 20, 40.0)

    def episode(form) -> list:
        env, rng, out = UrbanParallelEnv(files, "col"), np.random.default_rng(4), []
        env.reset(seed=4)
        while env.agents:
            action = rng.integers(0, 5, len(env.agents))
            obs, *rest = env.step(form(env.agents, action))
            out.append(({v: o.tolist() for v, o in obs.items()}, *rest, list(env.agents)))
        env.close()
        return out

    by_dict = episode(lambda agents, action: dict(zip(agents, action.tolist())))
    assert len(by_dict) > 20 and episode(lambda agents, action: action) == by_dict
    assert episode(lambda agents, action: action.tolist()) == by_dict  # a plain list is positional too, not ignored
    env = UrbanParallelEnv(files, "col")
    env.reset(seed=4)
    with pytest.raises(ValueError, match=rf"^actions: an array of shape \({len(env.agents) + 1},\), expected \({len(env.agents)},\)"):
        env.step(np.zeros(len(env.agents) + 1, int))
    with pytest.raises(ValueError, match=r"^actions: float64 values, expected integer action indices$"):
        env.step([0.5] * len(env.agents))
    env.close()


def test_agents_still_driving_at_the_time_limit_are_truncated(tmp_path, sc1_net):
    # an episode cut by its time limit (SUMO's last depart + slack) truncates the agents on the road, terminates none
    files, _ = make_copy(tmp_path / "c", sc1_net, 20, 40.0)
    env = UrbanParallelEnv(files, "col")
    env.reset(seed=4)
    env.sim.max_time_s = env.sim.ls.simulation.getTime() + 3.0  # the limit 3 decisions from now
    steps = []
    while env.agents:
        _, _, terminated, truncated, _ = env.step(np.full(len(env.agents), 2))
        steps.append((terminated, truncated))
    env.close()
    (terminated, truncated), earlier = steps[-1], steps[:-1]
    assert len(steps) == 3 and not any(v for _, tr in earlier for v in tr.values())
    assert truncated and any(truncated.values()) and all(truncated[v] == (not terminated[v]) for v in truncated)


def test_pettingzoo_parallel_api(tmp_path, sc1_net):
    from pettingzoo.test import parallel_api_test

    files, _ = make_copy(tmp_path / "c", sc1_net, 10, 40.0)
    parallel_api_test(UrbanParallelEnv(files, "ind"), num_cycles=200)


def test_bad_route_file_gives_one_clear_line(tmp_path, sc1_net):
    files, _ = make_copy(tmp_path / "c", sc1_net, 5, 20.0)
    broken = tmp_path / "c" / "broken.rou.xml"
    broken.write_text('<routes><route id="r" edges="no_such_edge"/><vehicle id="r.car.0" type="car" route="r" depart="0"/></routes>')
    sim = Simulation(ScenarioFiles(files.net, str(broken), files.folder, 0.0, 40.0))
    with pytest.raises(UrbanInputError, match="broken.rou.xml: SUMO cannot load.*no_such_edge") as e:
        sim.start()
    assert "\n" not in str(e.value)
    missing = ScenarioFiles(files.net, str(tmp_path / "none.rou.xml"), files.folder, 0.0, 40.0)
    with pytest.raises(UrbanInputError, match="scenario file not found"):
        Simulation(missing)
    with pytest.raises(UrbanInputError, match="none.rou.xml: scenario file not found"):
        UrbanParallelEnv(missing)


def _same_route_copy(folder, net, departs):
    """Cars on one straight route of Sc1 departing at `departs` (s)."""
    cars = "".join(f'  <vehicle id="r000.car.{i}" type="car" route="r000" depart="{t}" departSpeed="10" departPos="base"/>\n'
                   for i, t in enumerate(departs))
    return hand_copy(folder, net, f'  <route id="r000" edges="left0A0 A0right0"/>\n{cars}', float(max(departs)))


def _run_follower_into_leader(folder, net, leader_guard: bool):
    """The leader holds 10 m/s, its follower is told to accelerate into it; returns the follower's gaps (m) and the tally."""
    env = UrbanParallelEnv(_same_route_copy(folder, net, [0, 2]), leader_guard=leader_guard)
    obs, _ = env.reset(seed=0)
    gaps = []
    while env.agents:
        obs, *_ = env.step({a: HOLD if a.endswith(".0") else 4 for a in env.agents})
        follower = obs.get("r000.car.1")
        if follower is not None and follower[3] >= 0:  # it has a front vehicle
            gaps.append(follower[2] * 200.0)
    tally = env.sim.tally
    env.close()
    return gaps, tally


def test_front_gap_is_bumper_to_bumper_down_to_contact(tmp_path, sc1_net):
    # every SUMO check off: the gap must read as a gap (>= 0) all the way down to the rear-end collision, not as
    # "no front vehicle" once it is below SUMO's minGap (getLeader's distance excludes it)
    gaps, tally = _run_follower_into_leader(tmp_path / "follow", sc1_net, leader_guard=False)
    assert tally.collision_types == {"collision": 1}  # rear-end
    assert min(gaps) >= 0.0 and min(gaps) < 2.5


def test_car_following_safety_prevents_the_rear_end_and_keeps_turns_free(tmp_path, sc1_net):
    # the default: SUMO caps the follower at its safe speed behind the leader, so the same orders end without a collision
    gaps, tally = _run_follower_into_leader(tmp_path / "follow", sc1_net, leader_guard=True)
    assert not tally.collision_pairs and len(tally.arrive) == 2 and min(gaps) > 0.0
    # ... while junction crossings stay the agents' job (test_forced_crossing_is_a_collision runs the default too), and
    # neither turn speeds nor an acceleration law are imposed: a lone car turning left at full acceleration is as fast
    # as with every check off
    times = []
    for guard in (False, True):
        env = UrbanParallelEnv(crossing_copy(tmp_path / f"turn{guard}", sc1_net, turn=True), leader_guard=guard)
        env.reset(seed=0)
        while env.agents:
            env.step({a: 4 for a in env.agents})
        times.append(env.sim.metrics(1)["avg_travel_time_s"])
        env.close()
    assert times[1] == pytest.approx(times[0], abs=0.5)


def test_a_gap_in_traffic_does_not_end_the_episode(tmp_path, sc1_net):
    # one car every 40 s: between them nobody is a PettingZoo agent, yet every car must be simulated to its exit
    env = UrbanParallelEnv(_same_route_copy(tmp_path / "sparse", sc1_net, [0, 40, 80]))
    env.reset(seed=0)
    while env.agents:
        env.step({a: 4 for a in env.agents})
    metrics = env.sim.metrics(3)
    env.close()
    assert metrics["arrived"] == 3 and metrics["success"]
