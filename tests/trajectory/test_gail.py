"""Trajectory imitation on a real subset: metrics, environment, BC/GAIL learning, reload, determinism, CLI errors."""

import copy
from dataclasses import replace

import numpy as np
import polars as pl
import pytest
import torch

from models.parallel import ProcessPool
from models.trajectory.bc import train_bc, train_mode_classifier
from models.trajectory.data import TrajectoryDataError, demonstrations
from models.trajectory.env import DAY0_S
from models.trajectory.evaluate import evaluate_baselines, evaluate_model, evaluate_model_file, growth_table, metrics_table
from models.trajectory.metrics import matched_errors
from models.trajectory.model import TrajectoryModel, TrajectoryModelError, start_day
from models.trajectory.nets import Policy, Selector
from models.trajectory.predict import PredictionInputError, main, predict_flights, read_first_states
from models.trajectory.report import growth_rates
from models.trajectory.training import Budget, prepare, random_policy_like, train_and_save, train_model

torch.set_num_threads(1)


@pytest.fixture(scope="module")
def setup(aviation_tables):
    """The real pipeline on the bundled data: the foundation's tables -> demonstrations."""
    tracks20, modes, flights, splits, weather = aviation_tables
    return prepare(tracks20, modes, flights, splits, weather, 20.0), tracks20


@pytest.fixture(scope="module")
def trained(setup):
    return train_model(setup[0], "triple_gail", "SMIL", 0, Budget(bc_epochs=8, gail_iterations=2), "bce_gp")


def test_prepare_refuses_a_step_other_than_the_tracks(aviation_tables):
    tracks20, modes, flights, splits, weather = aviation_tables
    with pytest.raises(TrajectoryDataError, match="tracks_20s has a 20 s step but dt_s is 10 s"):
        prepare(tracks20, modes, flights, splits, weather, 10.0)


def test_matched_errors_units_and_zero():
    t = np.linspace(0, 1, 50)
    a = np.stack([20 + 2 * t, 55 + 0 * t, 10_000 + 0 * t], 1)
    assert matched_errors(a, a)["rmse_3d_nm"] == 0
    up = a.copy()
    up[:, 2] += 304.8  # 1000 ft higher: vertical error 1000 ft, no horizontal error
    e = matched_errors(a, up)
    assert e["vertical_ft"] == pytest.approx(1000)
    assert e["rmse_lat_nm"] == 0 and e["cte_nm"] == 0
    with pytest.raises(ValueError, match="shape"):
        matched_errors(a[:, :2], a)


def test_error_growth_rate_is_the_fit_over_every_rollout_minute():
    """Ten 10-minute roll-outs whose along-track error grows 0.1 nm/min, and one 20-minute roll-out that ends early and
    is held while the aircraft flies on (+6 nm/min after minute 10): the rate is the least-squares slope over all 120
    (minute, error) pairs, not over the 20 per-minute means, in which the one long roll-out sets the last 10 points."""
    key = {"method": "m", "scheme": "MMIL", "seed": 0, "phase": "descent"}
    rows = [{**key, "lookahead_min": m, "ate": 0.1 * m} for _ in range(10) for m in range(1, 11)]
    rows += [{**key, "lookahead_min": m, "ate": 0.1 * m + 6.0 * max(0, m - 10)} for m in range(1, 21)]
    rows = [{**r, "e3d": r["ate"], "cte": 0.0} for r in rows]
    rate = growth_rates(growth_table(rows))["ate_nm_per_min"][0]
    pooled = np.polyfit([r["lookahead_min"] for r in rows], [r["ate"] for r in rows], 1)[0]
    assert rate == pytest.approx(pooled)
    assert rate < 0.6 * np.polyfit(np.arange(1, 21), growth_table(rows)["ate_nm"].to_numpy(), 1)[0]


def test_modes_and_goals_come_from_training_flights_only(aviation_tables):
    """Move every flight of one cruise cluster to the test split: the training side (mode numbering, goals) is then
    exactly what it is without those flights, and they are labelled with their route's nearest training mode."""
    tracks, modes, flights, splits, _ = aviation_tables
    cruise = modes.filter(pl.col("phase") == "cruise").join(flights.select("flight_id", "route"), on="flight_id")
    sizes = cruise.group_by("route", "mode").len().filter(pl.len().over("route") >= 2).sort("len", "route", "mode")
    route, mode = sizes.row(0)[:2]
    moved = cruise.filter((pl.col("route") == route) & (pl.col("mode") == mode))["flight_id"].to_list()
    as_test = splits.with_columns(split=pl.when(pl.col("flight_id").is_in(moved)).then(pl.lit("test")).otherwise("split"))
    train, test = demonstrations(tracks, modes, flights, as_test, "cruise")
    alone, _ = demonstrations(tracks.filter(~pl.col("flight_id").is_in(moved)), modes, flights, as_test, "cruise")
    assert (route, mode) not in train.mode_keys and train.mode_keys == alone.mode_keys
    assert np.array_equal(train.goals, alone.goals) and np.array_equal(train.modes, alone.modes)
    relabelled = np.isin(test.flight_ids, moved)
    assert relabelled.any() and all(train.mode_keys[g][0] == route for g in test.modes[relabelled])
    # a test flight of a cluster that has training flights keeps its cluster
    kept = cruise.filter(pl.col("flight_id").is_in(test.flight_ids) & ~pl.col("flight_id").is_in(moved))
    truth = dict(zip(kept["flight_id"], zip(kept["route"], kept["mode"])))
    assert all(train.mode_keys[g] == truth[f] for f, g in zip(test.flight_ids, test.modes) if f in truth)


def test_env_steps_a_batch_and_terminates_at_the_goal(setup):
    s = setup[0]
    task = s.task("climb")
    idx = torch.arange(64)
    obs = s.env.reset(task.starts[idx], task.pair_goal[idx], 5, torch.zeros(64, dtype=torch.float64), task.start_day[idx])
    assert obs.shape == (64, task.obs.shape[1]) and torch.isfinite(obs).all()
    s.env.step(task.pair_goal[idx] - task.starts[idx])  # jump onto the goal: every trajectory succeeds
    assert s.env.done.all() and s.env.reached.all()


def test_losses_decrease_and_learned_policy_beats_random(setup, trained):
    model, history = trained
    h = history["all"]
    assert h["bc_loss"][-1] < 0.5 * h["bc_loss"][0]
    assert h["selector_warm_loss"][-1] < h["selector_warm_loss"][0]
    learned = metrics_table(evaluate_model(setup[0], model).errors)
    rnd = metrics_table(evaluate_model(setup[0], random_policy_like(model, 0)).errors)
    pick = lambda m: m.filter((pl.col("phase") == "total") & (pl.col("metric") == "rmse_3d_nm"))["mean"][0]  # noqa: E731
    assert pick(learned) < 0.5 * pick(rnd)


def test_predicted_mode_labels_name_the_flights_own_route(setup, trained):
    """trajectory_predictions.mode is the chosen mode of the flight's route; empty for BC, which has one mode per route
    (its mode index is a route index: read as a clustered mode it named the other route's modes)."""
    s = setup[0]
    test = s.demos["all"][1]
    route_of = dict(zip(test.flight_ids, test.routes))
    gail = evaluate_model(s, trained[0]).predictions
    assert all(p["mode"].split("/")[0] == route_of[p["flight_id"]] for p in gail)
    bc = train_model(s, "bc", "single", 0, Budget(bc_epochs=1, gail_iterations=0))[0]
    assert {p["mode"] for p in evaluate_model(s, bc).predictions} == {""}


def test_evaluation_refuses_a_model_trained_at_another_step(setup, trained):
    model = trained[0]
    other = TrajectoryModel({**model.config, "dt_s": 10.0}, model.phases, model.cube, model.bbox)
    with pytest.raises(TrajectoryDataError, match="trained with dt_s 10 s but the evaluation's is 20 s"):
        evaluate_model(setup[0], other)


def test_mode_mean_success_is_the_environments_goal_radius(setup):
    """The mode_mean baseline reaches its goal as the learned models do: within the environment's goal_radius_km
    (it used a flat 64/111 km-per-degree distance and a literal 10 km)."""
    def success(radius_km: float) -> set[float]:
        env = copy.copy(setup[0].env)
        env.cfg = replace(env.cfg, goal_radius_km=radius_km)
        errors = evaluate_baselines(replace(setup[0], env=env)).errors
        return {e["success"] for e in errors if e["method"] == "mode_mean" and e["phase"] == "total"}

    assert success(5_000.0) == {1.0}
    assert success(1e-6) == {0.0}


def test_saved_model_reloads_and_predicts_identically(setup, trained, tmp_path):
    model, _ = trained
    test = setup[0].demos["all"][1]
    starts = np.stack([p[0] for p in test.points[:4]])
    path = model.save(tmp_path / "m.pt")
    again = TrajectoryModel.load(path)
    a = model.predict(starts, test.routes[:4], test.start_s[:4])["all"][0]
    b = again.predict(starts, test.routes[:4], test.start_s[:4])["all"][0]
    assert all(np.array_equal(x, y) for x, y in zip(a.positions, b.positions))
    assert np.array_equal(a.modes, b.modes)
    assert path.with_suffix(".json").is_file()


def test_same_seed_same_metrics(setup, tmp_path):
    budget = Budget(bc_epochs=2, gail_iterations=1)
    here = train_model(setup[0], "sinfo_gail", "MMIL", 3, budget, "wgan_gp")[0]
    # again in a worker process, as the asset trains it (beside another bundle): the same model, the same metrics
    with ProcessPool(2, train_and_save) as pool:
        row, other_row = pool([(setup[0], "sinfo_gail", "MMIL", 3, budget, "wgan_gp", tmp_path, "demo"),
                       (setup[0], "triple_gail", "MMIL", 3, budget, "bce_gp", tmp_path, "demo")])
    # and evaluated in worker processes, as trajectory_evaluation does: the same metrics as in this process
    with ProcessPool(2, evaluate_model_file) as pool:
        (name, there), (other, _) = pool([(setup[0], row["path"]), (setup[0], other_row["path"])])
    assert (name, other) == ("sinfo_gail_wgan_gp_MMIL_seed3", "triple_gail_bce_gp_MMIL_seed3")
    assert metrics_table(evaluate_model(setup[0], here).errors).equals(metrics_table(there.errors))


def test_bad_model_files_give_one_line_errors(tmp_path):
    with pytest.raises(TrajectoryModelError, match="not found"):
        TrajectoryModel.load(tmp_path / "missing.pt")
    junk = tmp_path / "junk.pt"
    junk.write_bytes(b"not a torch file")
    with pytest.raises(TrajectoryModelError, match="not a trajectory model"):
        TrajectoryModel.load(junk)
    torch.save({"format": "something else"}, tmp_path / "other.pt")
    with pytest.raises(TrajectoryModelError, match="expected format"):
        TrajectoryModel.load(tmp_path / "other.pt")


def test_prediction_cli_and_bad_inputs(setup, trained, tmp_path, capsys):
    model, _ = trained
    path = model.save(tmp_path / "m.pt")
    first = setup[1].sort("flight_id", "ts").group_by("flight_id", maintain_order=True).first().head(3)
    first = first.join(pl.DataFrame({"flight_id": setup[0].demos["all"][1].flight_ids + setup[0].demos["all"][0].flight_ids,
                                     "route": setup[0].demos["all"][1].routes + setup[0].demos["all"][0].routes}), on="flight_id")
    flights = tmp_path / "first.parquet"
    first.write_parquet(flights)
    assert main(["--model", str(path), "--flights", str(flights), "--out", str(tmp_path / "out.parquet")]) == 0
    out = pl.read_parquet(tmp_path / "out.parquet")
    assert out["flight_id"].n_unique() == 3 and out["step"].min() == 0
    assert predict_flights(model, read_first_states(flights)).height == out.height
    assert main(["--model", str(path), "--flights", str(flights), "--out", str(tmp_path / "out.csv")]) == 0
    assert pl.read_csv(tmp_path / "out.csv").height == out.height  # the format the name says
    first.drop("route").write_parquet(tmp_path / "noroute.parquet")
    assert main(["--model", str(path), "--flights", str(tmp_path / "noroute.parquet"), "--out", str(tmp_path / "x.parquet")]) == 2
    assert "missing column(s) route" in capsys.readouterr().err
    first.with_columns(pl.col("alt_m") * 3.28084 * 10).write_parquet(tmp_path / "feet.parquet")
    with pytest.raises(PredictionInputError, match="feet"):
        read_first_states(tmp_path / "feet.parquet")
    assert main(["--model", str(tmp_path / "nope.pt"), "--flights", str(flights), "--out", str(tmp_path / "x.parquet")]) == 2
    assert "not found" in capsys.readouterr().err
    # lat and lon swapped: valid degrees, but far outside the area the model flies in (the roll-out ended at once)
    first.with_columns(lat=pl.col("lon"), lon=pl.col("lat")).write_parquet(tmp_path / "swapped.parquet")
    assert main(["--model", str(path), "--flights", str(tmp_path / "swapped.parquet"), "--out", str(tmp_path / "x.parquet")]) == 2
    err = capsys.readouterr().err
    assert "lies outside the area the model flies in" in err and "lat and lon swapped?" in err and len(err.strip().splitlines()) == 1
    # the area is the model's bounding box and the env's margin around it (where the env's roll-out goes on)
    _, _, _, lat1 = model.bbox
    margin = model.env.cfg.bbox_margin_deg
    one = read_first_states(flights).head(1)
    assert predict_flights(model, one.with_columns(lat=pl.lit(lat1 + margin / 2))).height > 0
    with pytest.raises(PredictionInputError, match="outside the area the model flies in"):
        predict_flights(model, one.with_columns(lat=pl.lit(lat1 + 1.5 * margin)))


@pytest.mark.parametrize("change, message", [
    (pl.col("alt_m") * float("nan"), "missing or NaN lon/lat/alt_m"),
    (pl.lit(None, pl.Float64).alias("alt_m"), "missing or NaN lon/lat/alt_m"),
    (pl.lit(None, pl.Float64).alias("lon"), "missing or NaN lon/lat/alt_m"),
    (pl.lit(-5000.0).alias("alt_m"), "below -500 m"),
    (None, "no rows"),
    (pl.lit("yesterday").alias("ts"), "column ts must be a UTC timestamp"),
])
def test_prediction_input_values_are_checked(tmp_path, change, message):
    first = pl.DataFrame({"flight_id": ["f1"], "ts": ["2022-02-27T04:12:20Z"], "lon": [37.5], "lat": [56.0], "alt_m": [1120.0], "route": ["UUEE-UMKK"]})
    (first.head(0) if change is None else first.with_columns(change)).write_csv(tmp_path / "f.csv")
    with pytest.raises(PredictionInputError, match=message):
        read_first_states(tmp_path / "f.csv")


def test_mode_selection_keeps_to_the_flights_side_of_the_airspace_closure(setup):
    """Cruise modes of ULLI-UMKK follow routes flown only before or only after the 2022-02-27 closure. Trained on expert
    pairs alone, the selector named each roll-out's own mode whatever the date, so held-out pre-closure flights were
    sent along the post-closure detour (mode accuracy 79 %, a wrong-side mode for 16-21 % of flights); with the
    candidate roll-outs in its training data every pick lies on the flight's own side of the closure."""
    s = setup[0]
    task, gen = s.task("cruise"), torch.Generator().manual_seed(0)
    torch.manual_seed(0)
    policy = Policy(task.n_modes, task.obs_scaler, task.act_scaler)
    train_bc(policy, task, 8, gen)
    selector = Selector(task.n_modes, task.obs_scaler)
    train_mode_classifier(selector, policy.eval(), task, 8, gen)
    model = TrajectoryModel.from_tasks({"name": "cruise", "dt_s": s.dt_s}, [task], [policy], [selector])
    test = s.demos["cruise"][1]
    starts = np.stack([p[0] for p in test.points])
    pred, _ = model.predict_phase(model.phases[0], starts, test.routes, test.start_s, np.zeros(len(starts)))
    closure_day = (np.datetime64("2022-02-27", "s").astype(np.int64) - DAY0_S) / 86400
    after = np.array([(task.start_day[task.modes == g] >= closure_day).float().mean().item() for g in range(task.n_modes)])
    own_side = np.where(start_day(test.start_s) >= closure_day, after[pred.modes] > 0, after[pred.modes] < 1)
    assert own_side.all(), [test.flight_ids[i] for i in np.flatnonzero(~own_side)]
    assert np.mean(pred.modes == test.modes) >= 0.85


def test_prediction_reads_iso_time_strings_from_parquet_as_from_csv(tmp_path):
    first = pl.DataFrame({"flight_id": ["f1"], "ts": ["2022-02-27T04:12:20Z"], "lon": [37.5], "lat": [56.0], "alt_m": [1120.0], "route": ["UUEE-UMKK"]})
    first.write_csv(tmp_path / "f.csv")
    first.write_parquet(tmp_path / "f.parquet")
    from_csv, from_parquet = read_first_states(tmp_path / "f.csv"), read_first_states(tmp_path / "f.parquet")
    assert from_parquet["ts"].dtype.is_temporal() and from_parquet["ts"].to_list() == from_csv["ts"].to_list()
