"""Tables of the trajectory-imitation models (issue 3): multi-modal GAIL under MMIL/SMIL, BC and baselines."""

import pyarrow as pa

from warehouse.table import TS, Table, col

_METHOD = col("method", pa.string(), "", "triple_gail_<disc>, sinfo_gail_<disc> (disc = bce_gp or wgan_gp), bc, constant_velocity or mode_mean")
_SCHEME = col("scheme", pa.string(), "", "MMIL (a model per phase, composed), SMIL (one model, whole flights) or single (no modes/phases)")
_SEED = col("seed", pa.int64(), "", "training seed (baselines are deterministic: 0)")

TABLES: list[Table] = [
    Table(
        "trajectory_models",
        "Catalogue of trained trajectory models: one row per method, scheme and seed, with its model file "
        "(state dicts + config, reloadable with TrajectoryModel.load / python -m models.trajectory.predict).",
        (
            col("name", pa.string(), "", "<method>_<scheme>_seed<seed>"),
            _METHOD,
            col("algorithm", pa.string(), "", "bc, triple_gail or sinfo_gail"),
            col("discriminator", pa.string(), "", "bce_gp or wgan_gp; null for bc", nullable=True),
            _SCHEME,
            _SEED,
            col("profile", pa.string(), "", "run profile: demo or paper"),
            col("bc_epochs", pa.int64(), "", "behavioural-cloning epochs (warm start for the GAILs)"),
            col("gail_iterations", pa.int64(), "", "adversarial iterations per phase model (roll-outs + D/selector + PPO)"),
            col("phases", pa.string(), "", "phase models in the bundle, comma-separated (all = whole flight)"),
            col("expert_pairs", pa.int64(), "", "expert state-action pairs the bundle was trained on"),
            col("final_bc_loss", pa.float64(), "", "mean BC loss of the last epoch (z-scored action units), averaged over phases"),
            col("train_s", pa.float64(), "s", "wall-clock training time"),
            col("path", pa.string(), "", "model file (.pt; the .json beside it is the same config, readable)"),
        ),
    ),
    Table(
        "trajectory_predictions",
        "Predicted trajectories of every TEST flight by every method and seed, from the flight's first state to its goal.",
        (
            col("flight_id", pa.string(), "", "test flight"),
            _METHOD,
            _SCHEME,
            _SEED,
            col("phase", pa.string(), "", "climb, cruise, descent (MMIL segments) or all (whole-flight models and baselines)"),
            col("step", pa.int64(), "", "step index from the flight's first state (0 = the given state)"),
            col("ts", TS, "UTC", "time of the predicted point: first state's time + step x dt"),
            col("lat", pa.float64(), "deg", "predicted latitude"),
            col("lon", pa.float64(), "deg", "predicted longitude"),
            col("alt_m", pa.float64(), "m", "predicted barometric altitude"),
            col("mode", pa.string(), "", "chosen mode as route/cluster id of that phase's clustering (empty for bc and constant_velocity)"),
        ),
    ),
    Table(
        "trajectory_metrics",
        "Prediction errors on held-out flights, long format: per method, scheme, phase and metric the mean and "
        "std over seeds of the per-seed mean over test flights.",
        (
            _METHOD,
            _SCHEME,
            col("phase", pa.string(), "", "climb, cruise, descent or total (whole flight)"),
            col(
                "metric",
                pa.string(),
                "",
                "rmse_lon_nm, rmse_lat_nm, rmse_alt_nm, rmse_3d_nm, ate_nm, cte_nm (nm, DTW-matched), vertical_ft (ft), "
                "eta_s (s), success_rate (0..1), mode_accuracy (0..1)",
            ),
            col("mean", pa.float64(), "metric's unit", "mean over seeds"),
            col("std", pa.float64(), "metric's unit", "population std over seeds (0 for one seed)"),
            col("n_seeds", pa.int64(), "", "seeds averaged"),
        ),
    ),
    Table(
        "trajectory_error_growth",
        "Error against minutes of look-ahead (Figs 7.11-7.13): phase-wise roll-outs from the actual phase start, "
        "time-aligned with the actual track, over test flights and seeds.",
        (
            _METHOD,
            _SCHEME,
            col("phase", pa.string(), "", "climb, cruise or descent"),
            col("lookahead_min", pa.int64(), "min", "minutes after the phase start"),
            col("rmse_3d_nm", pa.float64(), "nm", "root mean square 3D error at that minute"),
            col("ate_nm", pa.float64(), "nm", "mean absolute along-track error"),
            col("cte_nm", pa.float64(), "nm", "mean absolute cross-track error"),
            col("std_3d_nm", pa.float64(), "nm", "std of the 3D error over flights and seeds"),
            col("n", pa.int64(), "", "flight x seed samples at that minute (flights whose phase lasts that long)"),
        ),
    ),
    Table(
        "mode_posteriors",
        "Mean selector (Triple-GAIL) / posterior (sInfo-GAIL) probability of each mode on the actual test "
        "sub-trajectories, by true mode (Tables 7.6-7.8); probabilities are over the flight's route's modes.",
        (
            _METHOD,
            _SCHEME,
            col("phase", pa.string(), "", "climb, cruise, descent (MMIL) or all (SMIL)"),
            col("true_mode", pa.string(), "", "clustered mode route/id"),
            col("predicted_mode", pa.string(), "", "mode route/id the probability is for (the 'policy' column of the thesis tables)"),
            col("mean_probability", pa.float64(), "", "mean over test flights of that true mode and over seeds"),
            col("n_seeds", pa.int64(), "", "seeds averaged"),
        ),
    ),
    Table(
        "trajectory_report",
        "Files of the evaluation report: markdown of Tables 7.2-7.9, error-growth figures, rerun recording, MCAP export.",
        (
            col("item", pa.string(), "", "what the file shows, e.g. table_7_2, figure_7_11_climb, rerun, mcap"),
            col("kind", pa.string(), "", "markdown, png, rrd or mcap"),
            col("path", pa.string(), "", "file under TRAFFICLEARN_HOME"),
            col("size_bytes", pa.int64(), "B", "file size"),
        ),
    ),
]
