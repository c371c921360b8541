"""Tables of the urban traffic system (issue 4): SUMO scenarios, route agents, training, results, trajectories."""

import pyarrow as pa

from warehouse.table import Table, col, comparison_columns

_SCENARIO = col("scenario", pa.string(), "", "scenario name, e.g. sc1, sc4_x3 (knowledge reuse copy), real_mr")
_COPY = col("copy", pa.int64(), "", "seeded copy of the scenario (0-based)")
_METHOD = col("method", pa.string(), "", "col_marl, i_marl, ch3_dqn_cnn (chapter 3), idm or krauss")
_SEED = col("seed", pa.int64(), "", "training seed of the policy (col_marl, i_marl, ch3_dqn_cnn) or SUMO seed (idm, krauss)")
_AGENT = col("agent", pa.string(), "", "route agent: <route_id>:<car|heavy> (buses and trucks share the heavy agent)")

TABLES: list[Table] = [
    Table(
        "urban_routes",
        "Unsignalized road networks and the routes of their route agents (one row per network and route).",
        (
            col("network", pa.string(), "", "network name: sc1, sc2, sc4 (artificial), real (bundled Bologna), or a user network"),
            col("net_path", pa.string(), "", "unsignalized SUMO .net.xml (every junction right_before_left, no traffic lights)"),
            col("source", pa.string(), "", "how it was built: netgenerate grid, netconvert of a .net.xml or of an .osm"),
            col("n_junctions", pa.int64(), "", "junctions of the network, dead ends not counted"),
            col("max_speed_mps", pa.float64(), "m/s", "vel_max: speed limit of every road and top speed of the agents"),
            col("route_id", pa.string(), "", "route id (r000, r001, ...)"),
            col("edges", pa.string(), "", "SUMO edge ids of the route, space separated"),
            col("length_m", pa.float64(), "m", "route length"),
            col("n_junctions_crossed", pa.int64(), "", "junctions on the route"),
        ),
    ),
    Table(
        "urban_scenarios",
        "Seeded scenario copies: demand over a network, written as SUMO route and vehicle-type files.",
        (
            _SCENARIO,
            _COPY,
            col("network", pa.string(), "", "network of urban_routes"),
            col("role", pa.string(), "", "train (training episodes), eval (held-out copies) or reuse (2-5x longer, denser copies)"),
            col("policy_scenario", pa.string(), "", "scenario whose trained policies drive this copy"),
            col("arrival", pa.string(), "", "constant (one vehicle per duration/count s, 75/15/10 mix; cars only on Sc1/Sc2/Sc4 with artificial_cars_only) or ls (cars/buses/trucks every 4/10/15 s)"),
            col("noise_sigma_s", pa.float64(), "s", "std of the zero-mean Gaussian noise on every inter-arrival time (CR 0, MR 0.5, LR 1.0, LS_noisy 0.2)"),
            col("duration_s", pa.float64(), "s", "demand duration"),
            col("demand_seed", pa.int64(), "", "seed of the copy's departures, vehicle types and routes"),
            col("n_vehicles", pa.int64(), "", "vehicles"),
            col("n_cars", pa.int64(), "", "passenger cars"),
            col("n_buses", pa.int64(), "", "buses"),
            col("n_trucks", pa.int64(), "", "trucks"),
            col("last_depart_s", pa.float64(), "s", "departure of the last vehicle"),
            col("max_speed_mps", pa.float64(), "m/s", "vel_max"),
            col("net_path", pa.string(), "", "SUMO network"),
            col("routes_path", pa.string(), "", "SUMO routes file (routes and vehicles)"),
            col("folder", pa.string(), "", "folder with vtypes_idm.add.xml and vtypes_krauss.add.xml"),
        ),
    ),
    Table(
        "urban_training",
        "Training log of the route agents: one row per method, route agent and logged episode (every episode of a run under 400 episodes; a longer one every k-th, k = episodes // 200, and the last: LOG_EPISODES in models/urban/col_marl.py), with the model file.",
        (
            _SCENARIO,
            _METHOD,
            _SEED,
            _AGENT,
            col("episode", pa.int64(), "", "0-based training episode"),
            col("return", pa.float64(), "", "mean undiscounted return of the agent's vehicles in the episode (null: none)", nullable=True),
            col("epsilon", pa.float64(), "", "exploration probability of the episode"),
            col("loss", pa.float64(), "", "mean squared TD error of the agent's DDQN updates after the episode (null: empty buffer)", nullable=True),
            col("model_path", pa.string(), "", "policy file: weights, route agents and training config (models.urban.policy_file.load_policy)"),
        ),
    ),
    Table(
        "urban_results",
        "Evaluation: one row per scenario copy not used in training, method and seed (Tables 3.2, 4.3-4.9).",
        (
            _SCENARIO,
            _COPY,
            _METHOD,
            _SEED,
            col("avg_travel_time_s", pa.float64(), "s", "mean travel time of the vehicles that reached their destination", nullable=True),
            col("avg_speed_mps", pa.float64(), "m/s", "mean speed over 1 s samples of all vehicles", nullable=True),
            col("avg_fuel_mlps", pa.float64(), "ml/s", "mean fuel consumption over 1 s samples (SUMO HBEFA3 mg/s / fuel density)", nullable=True),
            col("collisions", pa.int64(), "", "distinct colliding vehicle pairs"),
            col("teleports", pa.int64(), "", "SUMO teleports (gridlock resolution), counted as failures"),
            col("arrived", pa.int64(), "", "vehicles that reached their destination"),
            col("n_vehicles", pa.int64(), "", "vehicles of the copy"),
            col("success", pa.bool_(), "", "no collision, no teleport and every vehicle arrived"),
        ),
    ),
    Table(
        "urban_trajectories",
        "Per-vehicle trajectories (SUMO floating car data at 1 s) of one evaluation episode per scenario and method.",
        (
            _SCENARIO,
            _METHOD,
            col("vehicle_id", pa.string(), "", "SUMO vehicle id <route>.<class>.<n>"),
            col("t", pa.float64(), "s", "simulation time"),
            col("x", pa.float64(), "m", "network x coordinate"),
            col("y", pa.float64(), "m", "network y coordinate"),
            col("speed_mps", pa.float64(), "m/s", "speed"),
            col("accel_mps2", pa.float64(), "m/s²", "acceleration"),
            col("route", pa.string(), "", "route id"),
            _AGENT,
            col("collided", pa.bool_(), "", "the vehicle was removed in a collision during the episode"),
            col("teleported", pa.bool_(), "", "SUMO teleported the vehicle (stuck 120 s) during the episode: its position jumps "
                "and the acceleration SUMO reports for that second is meaningless (e.g. -200 m/s²)"),
        ),
    ),
    Table(
        "urban_comparisons",
        "Paired comparisons over training seeds on the same held-out copies (exact sign-flip test): i-MARL against "
        "col-MARL (Table 4.3's question) and col-MARL with the safety layer against without.",
        (
            _SCENARIO,
            *comparison_columns("i_marl or col_marl_shield", "col_marl",
                                "collisions, teleports (per run), success (share of runs) or avg_travel_time_s (s)",
                                "; each seed's metric is its mean over the held-out copies both ran"),
        ),
    ),
    Table(
        "urban_thesis_tables",
        "The thesis's result tables (3.2, 4.3, 4.4, 4.5, 4.7-4.9) for our runs: mean and std over copies and seeds.",
        (
            col("thesis_table", pa.string(), "", "3.2, 4.3, 4.4, 4.5 or 4.7-4.9"),
            _SCENARIO,
            _METHOD,
            col("runs", pa.int64(), "", "evaluation runs (copies x seeds)"),
            col("travel_time_mean_s", pa.float64(), "s", "mean of avg_travel_time_s over successful runs (all runs if none)", nullable=True),
            col("travel_time_std_s", pa.float64(), "s", "std of the same", nullable=True),
            col("speed_mean_mps", pa.float64(), "m/s", "mean of avg_speed_mps", nullable=True),
            col("speed_std_mps", pa.float64(), "m/s", "std of avg_speed_mps", nullable=True),
            col("fuel_mean_mlps", pa.float64(), "ml/s", "mean of avg_fuel_mlps", nullable=True),
            col("fuel_std_mlps", pa.float64(), "ml/s", "std of avg_fuel_mlps", nullable=True),
            col("collisions_mean", pa.float64(), "", "mean collisions per run"),
            col("collisions_std", pa.float64(), "", "std of collisions per run", nullable=True),
            col("teleports_mean", pa.float64(), "", "mean teleports per run"),
            col("success_rate", pa.float64(), "", "share of runs with success"),
        ),
    ),
]
