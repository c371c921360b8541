"""Tables of AppLearn inverse RL and its SVM behavioural-cloning baseline (chapter 6, part of issue 3)."""

import pyarrow as pa

from warehouse.table import Table, col

_DATASET = col("dataset", pa.string(), "", "<route>/<mode>: a whole-flight cluster of trajectory_modes, one expert set (the thesis's 'cluster')")
_PARTITION = col("partition", pa.string(), "", "P1 (centroid flight only), P2 10/90, P3 50/50, P4 90/10 train/test (Table 6.1)")
_SEED = col("seed", pa.int64(), "", "seed of the train/test draw and of the training")

TABLES: list[Table] = [
    Table(
        "applearn_models",
        "Catalogue of trained AppLearn models (inverse RL, Alg 7): one per dataset, partition and seed, with its "
        "model file (reload with models.trajectory.applearn.AppLearnModel.load).",
        (
            _DATASET,
            _PARTITION,
            _SEED,
            col("profile", pa.string(), "", "run profile: demo or paper"),
            col("episodes", pa.int64(), "", "DQN training episodes"),
            col("n_train", pa.int64(), "", "expert (training) flights"),
            col("irl_steps", pa.int64(), "", "max-margin QP solves (a new w each)"),
            col("final_margin", pa.float64(), "", "margin t of the last QP: wᵀμ(π_E) − max_j wᵀμ(π_j), ‖w‖₂ ≤ 1"),
            col("final_train_success", pa.float64(), "", "share of the training episodes since the previous IRL step that reached the goal"),
            col("train_s", pa.float64(), "s", "wall-clock training time"),
            col("path", pa.string(), "", "model file (.pt: state dicts, w, features, geometry)"),
        ),
    ),
    Table(
        "applearn_results",
        "Thesis Table 6.1 protocol on held-out flights: per dataset, partition, method and seed, the success rate "
        "and the DTW-matched errors of the trajectories rolled out from every test flight's first point.",
        (
            _DATASET,
            _PARTITION,
            col("method", pa.string(), "", "applearn (inverse RL + DQN) or svm_bc (RBF-kernel SVM behavioural cloning)"),
            _SEED,
            col("n_test", pa.int64(), "", "test flights"),
            col("success_rate", pa.float64(), "", "share of test roll-outs ending within the goal radius (5 km) of the destination"),
            col("expert_success_rate", pa.float64(), "", "share of the actual test flights that pass within the goal radius (a ceiling for imitation)"),
            col("rmse_3d_km", pa.float64(), "km", "3D RMSE over DTW-matched points (lon, lat, alt), all test roll-outs, mean over flights"),
            col("rmse_3d_nm", pa.float64(), "nm", "the same in nautical miles"),
            col("cte_nm", pa.float64(), "nm", "cross-track error, mean over flights"),
            col("vertical_ft", pa.float64(), "ft", "vertical error, mean over flights"),
            col("mean_steps", pa.float64(), "", "mean roll-out length (steps of dt)"),
        ),
    ),
]
