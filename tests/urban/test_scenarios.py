"""Demand: 75/15/10 mix (cars only on the artificial networks as an option), constant or noisy arrivals, LS streams, seeded copies; the held-out copies evaluated."""

import numpy as np
import polars as pl
import pytest

from models.urban.experiments import EVALUATION_METHODS, METHODS_RL, METHODS_SHIELDED, METHODS_SUMO, evaluation_jobs, held_out, route_agents, scenarios
from models.urban.network import UrbanInputError
from models.urban.scenarios import Demand, vehicles


def test_constant_arrivals_and_mix():
    v = vehicles(Demand(200, 800.0), n_routes=12, seed=1)
    assert len(v["depart_s"]) == 200
    assert np.allclose(np.diff(v["depart_s"]), 4.0)  # one vehicle every 4 s (Table 4.2)
    kinds, counts = np.unique(v["vtype"], return_counts=True)
    assert dict(zip(kinds, counts)) == {"car": 150, "bus": 30, "truck": 20}
    assert set(v["route"]) == set(range(12))


def test_the_mix_everywhere_and_cars_only_on_the_artificial_networks_as_an_option():
    # default: the 75/15/10 mix on every network (issue 4); the option: cars only on Sc1/Sc2/Sc4, as Table 4.2's route agents
    for profile in ("demo", "paper"):
        for cars_only in (False, True):
            for spec in scenarios(profile, artificial_cars_only=cars_only):
                if spec.demand.arrival == "constant":
                    assert spec.demand.cars_only == (cars_only and spec.network.startswith("sc")), spec.name
    mixed, cars = (vehicles(Demand(200, 800.0, cars_only=c), n_routes=12, seed=1) for c in (False, True))
    assert set(cars["vtype"]) == {"car"}
    assert np.array_equal(cars["depart_s"], mixed["depart_s"]) and np.array_equal(cars["route"], mixed["route"])


def test_route_agents_only_for_the_vehicle_classes_a_scenario_carries():
    routes = pl.DataFrame({"network": ["sc1", "sc1", "real"], "route_id": ["r0", "r1", "r9"]})
    copies = pl.DataFrame({"network": ["sc1", "sc1"], "n_cars": [40, 40], "n_buses": [0, 0], "n_trucks": [0, 0]})
    assert route_agents(routes, copies) == ["r0:car", "r1:car"]
    assert route_agents(routes, copies.with_columns(n_trucks=pl.Series([0, 1]))) == ["r0:car", "r0:heavy", "r1:car", "r1:heavy"]


def test_noise_changes_gaps_but_not_the_mean_much():
    gaps = np.diff(vehicles(Demand(400, 1600.0, noise_sigma_s=1.0), 12, 3)["depart_s"])
    assert gaps.std() > 0.5 and abs(gaps.mean() - 4.0) < 0.2


def test_large_scale_streams():
    v = vehicles(Demand(0, 1800.0, "ls"), 30, 0)
    kinds, counts = np.unique(v["vtype"], return_counts=True)
    assert dict(zip(kinds, counts)) == {"car": 450, "bus": 180, "truck": 120}  # every 4 / 10 / 15 s for 30 min
    assert np.all(np.diff(v["depart_s"]) >= 0)


def test_same_seed_same_copy_other_seed_other_copy():
    a, b, c = (vehicles(Demand(50, 200.0, noise_sigma_s=0.5), 12, s) for s in (7, 7, 8))
    assert all(np.array_equal(a[k], b[k]) for k in a)
    assert not np.array_equal(a["route"], c["route"])


def test_held_out_copies_of_the_paper_profile_and_a_subset():
    df = pl.DataFrame([{"scenario": s.name, "copy": c, "role": "train" if c < s.train_copies else s.role}
                       for s in scenarios("paper") for c in range(s.train_copies + s.eval_copies)])
    every = held_out(df)
    assert every.height == 220 and (every["role"] != "train").all()  # 22 scenarios x 10 held-out copies
    sub = held_out(df, ["sc1", "sc4_x5"], copies=2)
    assert sorted(sub.select("scenario", "copy").rows()) == [("sc1", 5), ("sc1", 6), ("sc4_x5", 0), ("sc4_x5", 1)]
    with pytest.raises(UrbanInputError, match="sc9"):
        held_out(df, ["sc9"])
    with pytest.raises(UrbanInputError, match=">= 1"):
        held_out(df, copies=0)
    with pytest.raises(UrbanInputError, match=r"evaluation methods \['dqn'\]: expected some of col_marl"):
        evaluation_jobs(sub, {}, ["idm", "dqn"])


def test_every_method_is_evaluable_once():
    """urban_results' default list names each learned, shielded and SUMO method exactly once: a method added to one
    of the tables is evaluated by default, and one left out would be refused as unknown."""
    assert sorted(EVALUATION_METHODS) == sorted({*METHODS_RL, *METHODS_SHIELDED, *METHODS_SUMO})
