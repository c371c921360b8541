"""Trajectories (FCD), the Fig 4.4 profile and the rerun replay, from real recorded SUMO episodes."""

import polars as pl
import rerun as rr

from models.urban.col_marl import EpisodeJob
from models.urban.experiments import SumoJob, run_job, trajectories_rows
from models.urban.plots import busiest_route, junction_offsets_m, route_profile_png, route_profiles
from models.urban.recording import write_episode_recording
from urban_fixtures import constant_policy, crossing_copy, make_copy

AGENTS = ["r000:car", "r000:heavy", "r001:car", "r001:heavy"]


def test_trajectories_profile_and_recording(tmp_path, sc1_net):
    files, routes = make_copy(tmp_path / "c", sc1_net, 20, 80.0)
    cross = crossing_copy(tmp_path / "x", sc1_net)
    keys = [("sc1", 0, "idm", 0, 20), ("cross", 0, "col_marl", 0, 2)]
    outputs = [run_job(SumoJob(files, "IDM", 0, 20, record=True)),
               run_job(EpisodeJob(cross, "col", AGENTS, constant_policy(AGENTS, 2), 0.0, 0, 2, record=True))]
    traj = trajectories_rows(keys, outputs)
    idm, crossing = traj.filter(pl.col("scenario") == "sc1"), traj.filter(pl.col("scenario") == "cross")
    assert idm["vehicle_id"].n_unique() == 20 and not idm["collided"].any() and not idm["teleported"].any()
    assert crossing["collided"].all() and not crossing["teleported"].any() and set(crossing["agent"]) == {"r000:car", "r001:car"}

    route = busiest_route(idm, "idm")
    prof = route_profiles(idm, route)
    assert prof["bin_m"].min() == 0 and prof["speed_mps"].max() > 5
    junctions = junction_offsets_m(next(r["edges"] for r in routes if r["route_id"] == route), str(sc1_net))
    assert len(junctions) == 1 and route_profile_png(idm, route, junctions, "test")[:4] == b"\x89PNG"

    rrd = write_episode_recording(crossing, str(sc1_net), tmp_path / "ep.rrd", "test")
    entities = {str(c.entity_path) for c in rr.chunk.RrdReader(rrd).stream()}
    assert {"/vehicles", "/network/lanes"} <= entities and sum(e.startswith("/collisions/") for e in entities) == 2


def test_teleported_and_collided_vehicles_are_flagged_for_learners_and_baselines(tmp_path, sc1_net):
    # a car ordered to brake stands until SUMO teleports it (120 s): its rows say so (that second's position jump and
    # acceleration are SUMO's, not driving); the baselines' colliders are flagged as the learners' are
    lone = crossing_copy(tmp_path / "turn", sc1_net, turn=True)
    outputs = [run_job(EpisodeJob(lone, "col", ["r001:car"], constant_policy(["r001:car"], 0), 0.0, 0, 1, record=True))]
    assert outputs[0][3] == {"r001.car.0"}
    traj = trajectories_rows([("turn", 0, "col_marl", 0, 1)], outputs)
    assert traj["teleported"].all() and not traj["collided"].any()
    metrics, _, collided, teleported = run_job(SumoJob(crossing_copy(tmp_path / "x", sc1_net), "IDM", 0, 2))
    assert collided == set() and teleported == set() and metrics["success"]


def test_training_rows_without_return_or_loss_are_null_not_nan():
    from models.urban.experiments import training_frame

    rows = [{"agent": "r000:car", "episode": 0, "return": 0.5, "epsilon": 0.9, "loss": float("nan")},
            {"agent": "r000:heavy", "episode": 0, "return": float("nan"), "epsilon": 0.9, "loss": 0.25}]
    df = training_frame(rows, "sc1", "col_marl", 0, "/m.pt")
    assert df["return"].to_list() == [0.5, None] and df["loss"].to_list() == [None, 0.25]
    assert df.select(pl.col("return").mean()).item() == 0.5  # a mean over the agents, not NaN
    assert df.select("scenario", "method", "seed", "model_path").unique().rows() == [("sc1", "col_marl", 0, "/m.pt")]
