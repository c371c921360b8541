"""The optional safety layer (env.shield_masks): hand-built junction situations, the look-ahead's route table and the
env's look-ahead rows on a real two-junction network, and real SUMO episodes where it removes a forced collision and a
stall and where a car held by a full exit no longer holds the junction."""

import numpy as np
import pytest

from models.urban import env as E
from models.urban.col_marl import EpisodeJob, run_episode
from models.urban.env import SHIELD_BRAKE_HARD, SHIELD_UNSTALL, SHIELD_YIELD, UrbanParallelEnv, route_table, shield_masks
from models.urban.network import artificial_network, read_net
from models.urban.sim import NetIndex
from urban_fixtures import constant_policy, crossing_copy, hand_copy

FREE = [True] * 5


def _masks(rows, ahead_of=None, exit_room_m=None, waited_s=None):
    """rows: (junction, road, centre_dist_m, stop_dist_m, speed, internal) per row."""
    cols = [np.array(c) for c in zip(*rows)]
    ahead_of, exit_room_m, waited_s = (None if x is None else np.array(x) for x in (ahead_of, exit_room_m, waited_s))
    return shield_masks(*cols[:5], cols[5].astype(bool), ahead_of, exit_room_m, waited_s).tolist()


def test_a_vehicle_inside_the_junction_makes_an_approaching_one_yield():
    # 0 is inside junction 0, entered from road 0, at 8 m/s. 1 approaches from road 1, 40 m before the line at 12 m/s:
    # its last second to choose (it could still stop). 2 is 150 m out: it will be asked again.
    inside, approach = (0, 0, 3.0, 0.0, 8.0, 1), (0, 1, 47.0, 40.0, 12.0, 0)
    mask = _masks([inside, approach, (0, 2, 157.0, 150.0, 12.0, 0)])
    assert mask[0] == SHIELD_UNSTALL.tolist()  # inside: accelerates out
    assert mask[1] == SHIELD_YIELD.tolist()  # Decel_M (1.9 m/s² needed) still stops it before the line: both brakings allowed
    assert mask[2] == FREE
    # the same approach 25 m before the line: only Decel_L stops it
    assert _masks([inside, (0, 1, 32.0, 25.0, 12.0, 0)])[1] == SHIELD_BRAKE_HARD.tolist()
    # a follower on the occupant's own road is car following's business; unless the occupant crawls (their paths through
    # the junction may part, and SUMO sees a leader only on the same path)
    follower = (0, 0, 47.0, 40.0, 12.0, 0)
    assert _masks([inside, follower])[1] == FREE
    assert _masks([(0, 0, 3.0, 0.0, 2.0, 1), follower])[1] == SHIELD_YIELD.tolist()


def test_a_vehicle_with_no_conflict_may_not_stop_by_its_own_choice():
    # alone at their junctions: stopped -> must accelerate; at 6 m/s it may hold but not brake below SHIELD_STALL_MPS (5);
    # at 12 m/s Decel_L (-> 7 m/s) is allowed; 3 has no junction ahead (its last road): untouched
    mask = _masks([(0, 0, 17.0, 10.0, 0.0, 0), (1, 1, 57.0, 50.0, 6.0, 0), (2, 2, 57.0, 50.0, 12.0, 0), (-1, 3, 0.0, 0.0, 0.0, 0)])
    assert mask == [SHIELD_UNSTALL.tolist(), [False, False, True, True, True], FREE, FREE]


def test_the_earlier_arrival_goes_and_the_later_one_yields():
    # 0 and 1 reach junction 0's centre from different roads 0.4 s apart, both still able to stop: the earlier goes
    mask = _masks([(0, 0, 47.0, 40.0, 12.0, 0), (0, 1, 52.0, 45.0, 12.0, 0)])
    assert mask[0] == SHIELD_UNSTALL.tolist() and mask[1] == SHIELD_YIELD.tolist()
    # tie: the first in the list goes
    assert [m[0] for m in _masks([(0, 0, 47.0, 40.0, 12.0, 0), (0, 1, 47.0, 40.0, 12.0, 0)])] == [False, True]
    # a vehicle that can no longer stop before the line goes before an earlier one that still can (which brakes hard)
    committed = _masks([(0, 0, 52.0, 45.0, 20.0, 0), (0, 1, 22.0, 15.0, 10.0, 0)])
    assert committed[0] == SHIELD_UNSTALL.tolist() and committed[1] == SHIELD_BRAKE_HARD.tolist()
    # a stopped vehicle's arrival is its move-off time, not d / v: 2 m before the line it goes before one 60 m out at 15 m/s
    stopped = _masks([(0, 0, 9.0, 2.0, 0.0, 0), (0, 1, 67.0, 60.0, 15.0, 0)])
    assert stopped[0] == SHIELD_UNSTALL.tolist() and stopped[1] == SHIELD_YIELD.tolist()


def test_a_vehicle_whose_exit_is_full_gives_up_its_place():
    # 0 stands at the line of junction 0 (first by arrival), 1 stands 8 m back on another road: 1 waits for 0 ...
    rows = [(0, 0, 7.5, 0.5, 0.0, 0), (0, 1, 15.0, 8.0, 0.0, 0)]
    assert _masks(rows) == [SHIELD_UNSTALL.tolist(), SHIELD_YIELD.tolist()]
    # ... unless 0's exit road has no room for it (SUMO holds it at the line): then 0 waits and 1 goes (a gridlock of Sc4 x2:
    # every junction reserved for a vehicle that could not enter it)
    assert _masks(rows, exit_room_m=[5.0, np.inf]) == [SHIELD_YIELD.tolist(), SHIELD_UNSTALL.tolist()]
    assert _masks(rows, exit_room_m=[E.SHIELD_EXIT_ROOM_M, np.inf]) == [SHIELD_UNSTALL.tolist(), SHIELD_YIELD.tolist()]
    # a vehicle that can no longer stop before the line keeps its place whatever its exit (it enters anyway)
    fast = [(0, 0, 27.0, 20.0, 20.0, 0), (0, 1, 15.0, 8.0, 0.0, 0)]
    assert _masks(fast, exit_room_m=[5.0, np.inf]) == [SHIELD_UNSTALL.tolist(), SHIELD_YIELD.tolist()]


def test_a_vehicle_standing_beyond_patience_goes_before_a_moving_one():
    # 0 stands 8 m before junction 0 (move-off 3.46 s to the centre); 1 comes on another road at 12 m/s, 40 m out (2.99 s):
    # 1 is earlier and goes, 0 waits; so after 0 has stood SHIELD_PATIENCE_S + 0.3 s (credit 0.3 s: still later), but
    # not after + 0.6 s (credit 0.6 s: earlier): only the wait beyond patience counts
    rows = [(0, 0, 15.0, 8.0, 0.0, 0), (0, 1, 47.0, 40.0, 12.0, 0)]
    assert _masks(rows) == [SHIELD_YIELD.tolist(), SHIELD_UNSTALL.tolist()]
    assert _masks(rows, waited_s=[E.SHIELD_PATIENCE_S + 0.3, 0.0]) == [SHIELD_YIELD.tolist(), SHIELD_UNSTALL.tolist()]
    assert _masks(rows, waited_s=[E.SHIELD_PATIENCE_S + 0.6, 0.0]) == [SHIELD_UNSTALL.tolist(), SHIELD_YIELD.tolist()]


def test_look_ahead_rows_yield_to_vehicles_with_no_junction_before_theirs():
    # vehicle 0 is 10 m before junction 0 and then drives to junction 1 (look-ahead row: 32 m before its line), where
    # vehicle 1 arrives a little later, directly: 1 goes, 0 brakes; without the look-ahead row both would go on
    rows = [(0, 0, 17.0, 10.0, 12.0, 0), (1, 6, 45.0, 37.0, 12.0, 0), (1, 5, 40.0, 32.0, 12.0, 0)]
    mask = _masks(rows, ahead_of=[0])
    assert mask == [SHIELD_BRAKE_HARD.tolist(), SHIELD_UNSTALL.tolist()]
    assert _masks(rows[:2]) == [FREE, FREE]


def _straight_across_sc2(net):
    """Sc2's edges of a route across both junctions: in at a dead end, through the road between them, out at the other side."""
    sumo_net = read_net(net)
    middle = next(e for e in sumo_net.getEdges() if e.getFromNode().getType() != "dead_end" and e.getToNode().getType() != "dead_end")
    first = next(e for e in middle.getFromNode().getIncoming() if e.getFromNode().getType() == "dead_end" and
                 abs(e.getFromNode().getCoord()[1] - middle.getFromNode().getCoord()[1]) < 1)
    last = next(e for e in middle.getToNode().getOutgoing() if e.getToNode().getType() == "dead_end" and
                abs(e.getToNode().getCoord()[1] - middle.getToNode().getCoord()[1]) < 1)
    return first, middle, last


def test_route_table_places_the_junction_centres_along_the_route(tmp_path):
    net = artificial_network(2, tmp_path / "sc2.net.xml")  # two junctions 200 m apart
    index = NetIndex(str(net))
    first, middle, last = _straight_across_sc2(net)
    table = route_table(str(net), index, {"r": [first.getID(), middle.getID(), last.getID()]})
    gap = np.linalg.norm(np.subtract(middle.getToNode().getCoord(), middle.getFromNode().getCoord()))
    assert table.centre_m[0, 1] - table.centre_m[0, 0] == pytest.approx(gap, abs=0.5)
    assert table.junction[0].tolist() == [index.j_index[middle.getFromNode().getID()], index.j_index[middle.getToNode().getID()], -1]
    assert 0.0 < table.stop_to_centre_m[0, 1] < 15.0
    # from the first junction's centre to the road between the junctions: its internal lane's reach beyond the centre
    assert 0.0 < table.centre_to_exit_m[0, 0] < 15.0 and table.centre_to_exit_m[0, 2] == 0.0


def test_the_env_adds_a_look_ahead_row_for_the_next_junction_within_reach(tmp_path, monkeypatch):
    # one car through both junctions of Sc2 (centres 200 m apart): while it approaches the first, the env gives it a row
    # for the second once that is within SHIELD_LOOKAHEAD_M, at its own distance + 200 m, with the road between them
    net = artificial_network(2, tmp_path / "sc2.net.xml")
    first, middle, last = _straight_across_sc2(net)
    files = hand_copy(tmp_path / "across", net, f'  <route id="r000" edges="{first.getID()} {middle.getID()} {last.getID()}"/>\n'
                      '  <vehicle id="r000.car.0" type="car" route="r000" depart="0" departSpeed="10" departPos="base"/>\n')
    calls = []
    monkeypatch.setattr(E, "shield_masks", lambda *rows: calls.append([np.copy(r) for r in rows[:7]]) or np.ones((1, 5), bool))
    env = UrbanParallelEnv(files, shield=True)
    try:
        env.reset(seed=0)
        index = env.sim.index
        j1, j2 = index.j_index[middle.getFromNode().getID()], index.j_index[middle.getToNode().getID()]
        while env.agents:
            env.step({v: 4 for v in env.agents})
    finally:
        env.close()
    approaching_j1 = [c for c in calls if c[0][0] == j1 and not c[5][0]]
    near = [c for c in approaching_j1 if c[2][0] + 200.0 <= E.SHIELD_LOOKAHEAD_M - 1.0]
    far = [c for c in approaching_j1 if c[2][0] + 200.0 > E.SHIELD_LOOKAHEAD_M + 1.0]
    assert near and far
    for junction, road, centre, stop, _, internal, ahead_of in near:
        assert junction.tolist() == [j1, j2] and ahead_of.tolist() == [0] and not internal[1]
        assert road[1] == index.lane_road[index.lane_codes[f"{middle.getID()}_0"]]
        assert centre[1] - centre[0] == pytest.approx(200.0, abs=1.0) and 0.0 < centre[1] - stop[1] < 15.0
    assert all(len(c[0]) == 1 for c in far)
    assert all(len(c[0]) == 1 for c in calls if c[0][0] == j2)  # past the first junction: the second is its own row, then the goal


def test_shield_prevents_the_forced_crossing_and_the_stall(tmp_path, sc1_net):
    agents = ["r000:car", "r001:car"]
    cross = crossing_copy(tmp_path / "cross", sc1_net)  # two cars that meet in the junction if both hold their speed
    hold = [run_episode(EpisodeJob(cross, "col", agents, constant_policy(agents, 2), 0.0, 0, 2, shield=s)).metrics for s in (False, True)]
    assert hold[0]["collisions"] == 1
    assert hold[1]["collisions"] == 0 and hold[1]["arrived"] == 2 and hold[1]["success"]
    lone = crossing_copy(tmp_path / "turn", sc1_net, turn=True)  # one car alone: a policy that always brakes stops it for good
    brake = [run_episode(EpisodeJob(lone, "col", ["r001:car"], constant_policy(["r001:car"], 0), 0.0, 0, 1, shield=s)).metrics for s in (False, True)]
    assert brake[0]["teleports"] == 1 and not brake[0]["success"]  # SUMO teleports it after 120 s standing
    assert brake[1]["teleports"] == 0 and brake[1]["success"]


def test_without_the_arrival_window_the_forced_crossing_collides(tmp_path, sc1_net, monkeypatch):
    # what prevents the collision above is the arrival-time rule: with a zero window (only vehicles already inside the
    # junction count) both cars reach it together and collide, shield on
    monkeypatch.setattr(E, "SHIELD_WINDOW_S", 0.0)
    agents = ["r000:car", "r001:car"]
    m = run_episode(EpisodeJob(crossing_copy(tmp_path / "cross", sc1_net), "col", agents, constant_policy(agents, 2), 0.0, 0, 2, shield=True)).metrics
    assert m["collisions"] == 1


def _blocked_exit_copy(folder, net):
    """Sc1: a car stands 40 s on the first metres of road A0right0 (a stop), so r000's car, near the line by then, has no
    room to enter (a second r000 car queues behind it); r001's car starts at 15 s, standing 13 m before the line on the
    crossing road, its exit free."""
    return hand_copy(
        folder, net,
        '  <route id="r000" edges="left0A0 A0right0"/>\n  <route id="r001" edges="bottom0A0 A0top0"/>\n'
        '  <route id="r002" edges="A0right0"/>\n'
        '  <vehicle id="r002.car.0" type="car" route="r002" depart="0" departSpeed="0" departPos="5">'
        '<stop lane="A0right0_0" endPos="12" duration="40"/></vehicle>\n'
        '  <vehicle id="r000.car.1" type="car" route="r000" depart="0" departSpeed="10" departPos="base"/>\n'
        '  <vehicle id="r000.car.3" type="car" route="r000" depart="5" departSpeed="10" departPos="base"/>\n'
        '  <vehicle id="r001.car.2" type="car" route="r001" depart="15" departSpeed="0" departPos="180"/>\n', 15.0,
    )


def _arrivals_accelerating(files, shield_calls: list | None = None) -> dict:
    """The "always accelerate" policy under the layer (full acceleration where allowed, else the first allowed action, as
    run_episode's masked argmax of a constant Q does); arrival time per vehicle. shield_calls: filled with (vehicle ids,
    exit room, waited, internal) of every decision's call of the layer."""
    env = UrbanParallelEnv(files, shield=True)
    if shield_calls is not None:
        real, snapshot = E.shield_masks, env._shield

        def spy(*rows):
            shield_calls.append((ids[-1], rows[7][: len(ids[-1])].copy(), rows[8].copy(), rows[5][: len(ids[-1])].copy()))
            return real(*rows)

        def shield(snap, *rest):
            ids.append(list(snap.ids))
            return snapshot(snap, *rest)

        ids, env._shield = [], shield
        E.shield_masks = spy
    try:
        _, infos = env.reset(seed=0)
        while env.agents:
            _, _, _, _, infos = env.step({v: 4 if infos[v]["action_mask"][4] else int(infos[v]["action_mask"].argmax()) for v in env.agents})
        assert not env.sim.tally.collision_pairs and not env.sim.tally.teleported
        return dict(env.sim.tally.arrive)
    finally:
        env.close()
        if shield_calls is not None:
            E.shield_masks = real


def test_a_car_held_by_a_full_exit_does_not_hold_the_junction(tmp_path, sc1_net, monkeypatch):
    # the env's own path: exit room from SUMO's leader across the junction and the route table's centre-to-exit distance.
    # r000's car reaches the line first and stands before it until the stop ends (~44 s); r001's car crosses at once
    files = _blocked_exit_copy(tmp_path / "blocked", sc1_net)
    calls = []
    arrive = _arrivals_accelerating(files, calls)
    assert arrive["r001.car.2"] - 15.0 < 15.0 and arrive["r000.car.1"] > 44.0
    # the room the env measured for r000's car: once the other car stands, its rear is 7 m into A0right0 (its stop ends at
    # 12 m, a car is 5 m long; less while it creeps there, more as it drives off); no limit once it is off (or inside)
    first = [(room[i], internal[i]) for ids, room, _, internal in calls for i, v in enumerate(ids) if v == "r000.car.1"]
    blocked = [r for r, inside in first if np.isfinite(r)]
    assert blocked and all(r < E.SHIELD_EXIT_ROOM_M for r in blocked) and 6.0 < np.median(blocked) < 7.5
    assert not any(inside for r, inside in first if np.isfinite(r)) and np.isinf(first[-1][0])
    # waiting counts for the first car of a road only: the car queued behind r000's has waited 0 throughout
    waited = {v: [w[i] for ids, _, w, _ in calls for i, u in enumerate(ids) if u == v] for v in ("r000.car.1", "r000.car.3")}
    assert max(waited["r000.car.1"]) > 20.0 and max(waited["r000.car.3"]) == 0.0
    # without the exit rule r001's car waits behind the reservation of the car that cannot enter
    monkeypatch.setattr(E, "SHIELD_EXIT_ROOM_M", -np.inf)
    assert _arrivals_accelerating(files)["r001.car.2"] > arrive["r000.car.1"]
