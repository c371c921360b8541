"""Evaluation on held-out (test) flights: predictions, per-flight errors, error growth and mode posteriors,
then aggregation into the warehouse tables (mean ± std over seeds).

Protocol (thesis §7.5.3-7.5.4):
- total: every method predicts the whole flight from its first state (MMIL composes its phase models, each
  phase starting where the previous ended); compared with the whole actual track.
- per phase, MMIL: its composed phase segments against the actual phase segments (ETA = phase duration error,
  success = the phase's goal region reached, mode accuracy = the selected phase mode is the clustered one).
- per phase, SMIL and single-scheme methods (Tables 7.4-7.5): roll out from the actual phase start for the
  actual phase's number of steps (no goal of their own, so no ETA/success rows there).
- error growth (Figs 7.11-7.13): every method's phase-wise roll-out from the actual phase start (MMIL: its
  phase model), time-aligned error at each minute of look-ahead.
"""

from dataclasses import dataclass, field

import numpy as np
import polars as pl

from models.trajectory.baselines import mode_means, predict_constant_velocity, predict_mode_mean
from models.trajectory.data import PHASES, TrajectoryDataError
from models.trajectory.metrics import METRIC_NAMES, error_growth, haversine_km, matched_errors
from models.trajectory.model import TrajectoryModel
from models.trajectory.training import Setup

GROWTH_HORIZON_MIN = 60


@dataclass
class Results:
    predictions: list[dict] = field(default_factory=list)
    errors: list[dict] = field(default_factory=list)  # one per (method, scheme, seed, phase, flight)
    growth: list[dict] = field(default_factory=list)
    posteriors: list[dict] = field(default_factory=list)

    def extend(self, other: "Results") -> None:
        for k in ("predictions", "errors", "growth", "posteriors"):
            getattr(self, k).extend(getattr(other, k))


@dataclass
class TestFlights:
    ids: list[str]
    routes: list[str]
    start_s: np.ndarray
    whole: list[np.ndarray]
    phase: dict[str, dict[str, tuple[np.ndarray, float, int]]]  # phase -> flight -> (points, start_s, global mode)
    whole_mode: dict[str, int]


def test_flights(setup: Setup) -> TestFlights:
    test = setup.demos["all"][1]
    phase = {p: {f: (pts, s, m) for f, pts, s, m in zip(d.flight_ids, d.points, d.start_s, d.modes)}
             for p, (_, d) in setup.demos.items() if p in PHASES}
    return TestFlights(test.flight_ids, test.routes, test.start_s, test.points, phase, dict(zip(test.flight_ids, test.modes)))


def _mode_label(setup: Setup, phase: str, g: int) -> str:
    route, k = setup.demos[phase][0].mode_keys[g]
    return f"{route}/{k}"


def _error_row(key: dict, flight: str, actual: np.ndarray, pred: np.ndarray, **extra) -> dict:
    return {**key, "flight_id": flight, **matched_errors(actual, pred), **extra}


def _growth_rows(key: dict, phase: str, actual: np.ndarray, pred: np.ndarray, dt_s: float) -> list[dict]:
    horizon = min(GROWTH_HORIZON_MIN, int((len(actual) - 1) * dt_s // 60))
    if horizon < 1:
        return []
    g = error_growth(actual, pred, dt_s, horizon)
    return [{**key, "phase": phase, "lookahead_min": m + 1, "e3d": g[m, 0], "ate": g[m, 1], "cte": g[m, 2]} for m in range(horizon)]


def _prediction_rows(key: dict, flight: str, phase: str, pts: np.ndarray, start_s: float, dt_s: float, mode: str, step0: int) -> list[dict]:
    steps = np.arange(len(pts)) + step0
    return [{**key, "flight_id": flight, "phase": phase, "step": int(s), "ts_s": start_s + s * dt_s,
             "lon": p[0], "lat": p[1], "alt_m": p[2], "mode": mode} for s, p in zip(steps, pts)]


def _fixed_length_rollouts(model: TrajectoryModel, actual: list[np.ndarray], routes: list[str], flight_start_s: np.ndarray,
                           phase_start_s: np.ndarray) -> list[np.ndarray]:
    """A whole-flight model rolled out from each actual phase start for that phase's number of steps
    (one batched roll-out per distinct length)."""
    pm, preds = model.phases[0], [None] * len(actual)
    lengths = np.array([len(a) - 1 for a in actual])
    for n in np.unique(lengths):
        sel = np.flatnonzero(lengths == n)
        pr, _ = model.predict_phase(pm, np.stack([actual[k][0] for k in sel]), [routes[k] for k in sel], flight_start_s[sel],
                                    phase_start_s[sel] - flight_start_s[sel], max_steps=int(n))
        for j, k in enumerate(sel):
            preds[k] = pr.positions[j]
    return preds


def evaluate_model(setup: Setup, model: TrajectoryModel) -> Results:
    cfg, dt = model.config, setup.dt_s
    if cfg.get("dt_s", dt) != dt:  # a roll-out step other than the training one moves the aircraft by the wrong distance
        raise TrajectoryDataError(f"model {cfg['name']} was trained with dt_s {cfg['dt_s']:g} s but the evaluation's is {dt:g} s: "
                                  "set dt_s of trajectory_evaluation to the models'")
    key = {"method": cfg["method"], "scheme": cfg["scheme"], "seed": cfg["seed"]}
    tf, res = test_flights(setup), Results()
    starts = np.stack([w[0] for w in tf.whole])
    out = model.predict(starts, tf.routes, tf.start_s)
    # total (and, for MMIL, the composed phase segments)
    step0 = np.zeros(len(tf.ids), dtype=int)
    for pm in model.phases:
        pred, _ = out[pm.phase]
        for i, f in enumerate(tf.ids):
            pts = pred.positions[i]
            res.predictions += _prediction_rows(key, f, pm.phase, pts, tf.start_s[i], dt, pm.mode_label(pred.modes[i]), step0[i])
            step0[i] += len(pts) - 1
            if pm.phase in PHASES and f in tf.phase[pm.phase]:
                actual, _, true_mode = tf.phase[pm.phase][f]
                res.errors.append(_error_row({**key, "phase": pm.phase}, f, actual, pts,
                                             eta_s=abs(len(pts) - len(actual)) * dt, success=float(pred.reached[i]),
                                             mode_ok=float(pred.modes[i] == true_mode)))
    for i, f in enumerate(tf.ids):
        full = np.concatenate([out[pm.phase][0].positions[i][(1 if k else 0):] for k, pm in enumerate(model.phases)])
        ok = np.mean([out[pm.phase][0].reached[i] for pm in model.phases]) == 1.0
        extra = {"mode_ok": float(out["all"][0].modes[i] == tf.whole_mode[f])} if "all" in out and cfg["algorithm"] != "bc" else {}
        res.errors.append(_error_row({**key, "phase": "total"}, f, tf.whole[i], full,
                                     eta_s=abs(len(full) - len(tf.whole[i])) * dt, success=float(ok), **extra))
    # phase-wise roll-outs from the actual phase starts: error growth for all; phase errors for non-modular
    for phase in PHASES:
        flights = [f for f in tf.ids if f in tf.phase[phase]]
        if not flights:
            continue
        idx = [tf.ids.index(f) for f in flights]
        actual = [tf.phase[phase][f][0] for f in flights]
        p_start = np.array([tf.phase[phase][f][1] for f in flights])
        routes = [tf.routes[i] for i in idx]
        if cfg["scheme"] == "MMIL":
            pm = next(p for p in model.phases if p.phase == phase)
            preds = model.predict_phase(pm, np.stack([a[0] for a in actual]), routes, p_start, np.zeros(len(actual)))[0].positions
        else:
            preds = _fixed_length_rollouts(model, actual, routes, tf.start_s[idx], p_start)
            for f, a, p in zip(flights, actual, preds):
                res.errors.append(_error_row({**key, "phase": phase}, f, a, p))
        for a, p in zip(actual, preds):
            res.growth += _growth_rows(key, phase, a, p, dt)
        if cfg["algorithm"] != "bc":
            pm_post = next(p for p in model.phases if p.phase in (phase, "all"))
            post_phase = pm_post.phase
            src = tf.phase[phase] if post_phase == phase else {f: (tf.whole[tf.ids.index(f)], tf.start_s[tf.ids.index(f)], tf.whole_mode[f]) for f in flights}
            for f, r in zip(flights, routes):
                pts, s, true_mode = src[f]
                probs = model.mode_probs_on(pm_post, pts, r, s)
                for g in pm_post.candidates(r):
                    res.posteriors.append({**key, "phase": post_phase, "true_mode": _mode_label(setup, post_phase, true_mode),
                                           "predicted_mode": _mode_label(setup, post_phase, g), "probability": probs[g]})
    return res


def evaluate_model_file(job: tuple) -> tuple[str, Results]:
    """`evaluate_model(setup, TrajectoryModel.load(path))` for a worker process: (setup, path) -> (model name, results).
    Roll-outs are deterministic (policy means, fixed mode selection), so the results do not depend on where it ran."""
    setup, path = job
    model = TrajectoryModel.load(path)
    return model.config["name"], evaluate_model(setup, model)


def evaluate_baselines(setup: Setup) -> Results:
    """constant_velocity and mode_mean, total and phase-wise (deterministic: reported as seed 0)."""
    tf, res, dt = test_flights(setup), Results(), setup.dt_s
    radius_km = setup.env.cfg.goal_radius_km  # success as the environment counts it for the learned models
    train_all = setup.demos["all"][0]
    route_goal = {r: np.mean([p[-1] for p, rr in zip(train_all.points, train_all.routes) if rr == r], axis=0) for r in set(train_all.routes)}
    max_steps = int(1.5 * max(len(p) for p in train_all.points))
    cases = [("total", tf.ids, tf.whole, tf.start_s, tf.routes)]
    for phase in PHASES:
        fl = [f for f in tf.ids if f in tf.phase[phase]]
        cases.append((phase, fl, [tf.phase[phase][f][0] for f in fl], np.array([tf.phase[phase][f][1] for f in fl]),
                      [tf.routes[tf.ids.index(f)] for f in fl]))
    for phase, flights, actual, start_s, routes in cases:
        demos_phase = "all" if phase == "total" else phase
        train = setup.demos[demos_phase][0]
        means = mode_means(train)
        mm, mm_modes = predict_mode_mean(means, train, actual, routes)
        goals = np.stack([route_goal[r] for r in routes]) if phase == "total" else np.stack([train.goals[m] for m in mm_modes])
        cv, cv_reached = predict_constant_velocity(setup.env, actual, goals, start_s, max_steps if phase == "total" else
                                                   max(len(a) for a in actual))
        for method, preds in (("constant_velocity", cv), ("mode_mean", mm)):
            key = {"method": method, "scheme": "single", "seed": 0}
            for i, (f, a, p) in enumerate(zip(flights, actual, preds)):
                if phase == "total":
                    ok = cv_reached[i] if method == "constant_velocity" else haversine_km(p[-1, :2], goals[i, :2]) <= radius_km
                    res.errors.append(_error_row({**key, "phase": phase}, f, a, p, eta_s=abs(len(p) - len(a)) * dt, success=float(ok)))
                    label = _mode_label(setup, "all", mm_modes[i]) if method == "mode_mean" else ""
                    res.predictions += _prediction_rows(key, f, "all", p, start_s[i], dt, label, 0)
                else:
                    res.errors.append(_error_row({**key, "phase": phase}, f, a, p[: len(a)] if method == "constant_velocity" else p))
                    res.growth += _growth_rows(key, phase, a, p, dt)
    return res


# --- aggregation into tables ---------------------------------------------------------------------
def metrics_table(errors: list[dict]) -> pl.DataFrame:
    """Mean over flights per seed, then mean ± std over seeds, long format (one row per metric)."""
    df = pl.DataFrame(errors, infer_schema_length=None)  # rows differ in keys (eta/success/mode only where defined)
    metric_cols = [c for c in (*METRIC_NAMES, "eta_s", "success", "mode_ok") if c in df.columns]
    per_seed = df.group_by("method", "scheme", "seed", "phase").agg(pl.col(c).mean() for c in metric_cols)
    long = per_seed.unpivot(index=["method", "scheme", "seed", "phase"], on=metric_cols, variable_name="metric").drop_nulls("value")
    long = long.with_columns(pl.col("metric").replace({"success": "success_rate", "mode_ok": "mode_accuracy"}))
    return (long.group_by("method", "scheme", "phase", "metric")
            .agg(pl.col("value").mean().alias("mean"), pl.col("value").std(ddof=0).alias("std"), pl.len().cast(pl.Int64).alias("n_seeds"))
            .sort("method", "scheme", "phase", "metric"))


def growth_table(growth: list[dict]) -> pl.DataFrame:
    df = pl.DataFrame(growth, infer_schema_length=None)
    return (df.group_by("method", "scheme", "phase", "lookahead_min")
            .agg((pl.col("e3d") ** 2).mean().sqrt().alias("rmse_3d_nm"), pl.col("ate").mean().alias("ate_nm"),
                 pl.col("cte").mean().alias("cte_nm"), pl.col("e3d").std(ddof=0).alias("std_3d_nm"), pl.len().cast(pl.Int64).alias("n"))
            .with_columns(pl.col("lookahead_min").cast(pl.Int64))
            .sort("method", "scheme", "phase", "lookahead_min"))


def posterior_table(posteriors: list[dict]) -> pl.DataFrame:
    df = pl.DataFrame(posteriors, infer_schema_length=None)
    return (df.group_by("method", "scheme", "phase", "true_mode", "predicted_mode")
            .agg(pl.col("probability").mean().alias("mean_probability"), pl.col("seed").n_unique().cast(pl.Int64).alias("n_seeds"))
            .sort("method", "scheme", "phase", "true_mode", "predicted_mode"))


def predictions_table(predictions: list[dict]) -> pl.DataFrame:
    df = pl.DataFrame(predictions, infer_schema_length=None)
    return df.with_columns(pl.from_epoch((pl.col("ts_s") * 1e6).round().cast(pl.Int64), time_unit="us").dt.replace_time_zone("UTC").alias("ts")).select(
        "flight_id", "method", "scheme", "seed", "phase", pl.col("step").cast(pl.Int64), "ts", "lat", "lon", "alt_m", "mode")
