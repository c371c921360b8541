"""Every learner (MIRL, CMARL, HCMARL, stHMIRL, sHMIRL, tHMIRL) on every case and seed -> delays per flight."""

import dagster as dg
import polars as pl
from pydantic import Field

from assets.dcb.cases import problems
from assets.figures import add_plot
from assets.profiles import check_names, default_profile, resolve
from models.dcb.experiment import curve_rows, delay_rows
from models.dcb.mirl import LEARNING_RATE
from models.dcb.plots import learning_curves
from models.dcb.problem import C_PLUS
from models.dcb.train import METHODS, check_options, train_job
from models.parallel import ProcessPool, usable_cores

# per profile: episodes per abstraction level and seeds; the thesis trains 15,000 episodes per level, 10 seeds
PROFILE = {"demo": {"episodes": 200, "seeds": [0, 1, 2]}, "paper": {"episodes": 15000, "seeds": list(range(10))}}


class TrainingConfig(dg.Config):
    profile: str = Field(default_factory=default_profile, description="demo: 200 episodes per level, seeds 0-2; paper: 15,000 episodes, seeds 0-9")
    episodes: int | None = Field(default=None, description="training episodes per abstraction level (None: the profile's)")
    seeds: list[int] | None = Field(default=None, description="training seeds (None: the profile's)")
    methods: list[str] = Field(default=list(METHODS), description="learners to train: " + ", ".join(METHODS))
    state: str = Field(default="thesis", description="local state: thesis (d_i, h_i) or extended (d_i, h_i, x_i: among the flights cheapest to push out of its hotspot)")
    reward: str = Field(default="thesis", description="thesis (Eq 5.2-5.4 per flight), difference (each flight's own change of the day's Eq 5.2 total) "
                        "or overload (each flight's own change of the day's entries beyond capacity)")
    learning_rate: float = Field(default=LEARNING_RATE, description="η of the Q updates (Eq 5.6, 5.7); the thesis's 0.01 is tuned for 15,000 episodes")
    readout: str = Field(default="repair", description="repair: the greedy rollout and the best training episode with hotspots left resolved FCFS "
                         "and unneeded delay trimmed; best_episode: the two as they are (the better one is returned)")
    hold: str = Field(default="wait", description="wait: a flight that holds acts again at the next step while in a hotspot; depart: holding (or leaving "
                      "every hotspot) is departing, the flight never acts again in the episode (§5.4; thesis state and reward only)")
    c_plus: float = Field(default=C_PLUS, description="C+ of Eq 5.3, the reward of a flight in no hotspot (a large positive constant; the value is ours)")
    workers: int | None = Field(default=None, description="runs (case, method, seed) in parallel, one process each (None: usable cores); "
                                "every run seeds itself, so the delays do not depend on it")


def training_plan(config: TrainingConfig) -> dict:
    """episodes and seeds of the config or its profile; one line, before any training, for an unknown or no method
    or an option the learners cannot use."""
    check_names("DCB methods", config.methods, METHODS)
    check_options(config.state, config.reward, config.learning_rate, config.readout, config.hold, config.c_plus)
    return resolve(config, PROFILE)


@dg.asset(group_name="dcb", description="Ground delay of every flight in each learner's solution, per case and seed.")
def dcb_delays(context: dg.AssetExecutionContext, config: TrainingConfig, dcb_cases: pl.DataFrame, dcb_sector_entries: pl.DataFrame,
               dcb_sectors: pl.DataFrame, dcb_flights: pl.DataFrame) -> dg.Output:
    plan = training_plan(config)
    episodes, seeds = plan["episodes"], plan["seeds"]
    options = {"state": config.state, "reward": config.reward, "learning_rate": config.learning_rate, "readout": config.readout,
               "hold": config.hold, "c_plus": config.c_plus}
    todo = [(case, problem, method, seed) for case, problem in problems(dcb_cases, dcb_sector_entries, dcb_sectors, dcb_flights).items()
            for method in config.methods for seed in seeds]
    frames, runs, curves = [], [], []
    with ProcessPool(config.workers or usable_cores(), train_job) as pool:
        jobs = [(problem, method, seed, episodes, options) for _, problem, method, seed in todo]
        for k, ((case, problem, method, seed), r) in enumerate(zip(todo, pool.iter(jobs)), 1):
            frames.append(delay_rows(case, method, seed, problem, r.delay_min, r.runtime_s, policy=r))
            runs.append({"case": case, "method": method, "seed": seed, "runtime_s": round(r.runtime_s, 1), "hotspots_left": r.hotspots_left,
                         "total_delay_min": int(r.delay_min.sum()), "solution": r.source,
                         "greedy_hotspots_left": r.greedy_hotspots, "greedy_total_delay_min": r.greedy_delay_min})
            curves.append(curve_rows(case, method, seed, r))
            context.log.info(f"[{k}/{len(todo)}] {runs[-1]}")
    metadata = {"episodes_per_level": episodes, "seeds": dg.MetadataValue.json(seeds), "state": config.state, "reward": config.reward,
                "learning_rate": config.learning_rate, "readout": config.readout, "hold": config.hold, "c_plus": config.c_plus,
                "runs": dg.MetadataValue.json(runs)}
    add_plot(metadata, "dcb_learning_curves", learning_curves(pl.concat(curves), episodes))
    return dg.Output(pl.concat(frames), metadata=metadata)
