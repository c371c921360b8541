"""Traffic demand and SUMO scenario files: vehicle classes (Table 4.1), arrivals, seeded copies.

A scenario copy is three files in one folder: the unsignalized network, `vtypes_<model>.add.xml` (one per
driver model: the agents' vehicles use Krauss's file under leader_guard, IDM's without it and in chapter 3's
variant, but are driven by the env (models.urban.env); the baselines use IDM or Krauss) and `routes.rou.xml`
(route definitions and the vehicles, sorted by departure).
"""

from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import quoteattr

import numpy as np

# Table 4.1: accelerations (m/s²) per vehicle class; buses and trucks share one route agent ("heavy").
ACTIONS_MPS2 = {
    "car": (-5.0, -2.5, 0.0, 1.5, 3.0),
    "heavy": (-4.0, -2.0, 0.0, 0.75, 1.5),
}


@dataclass(frozen=True)
class VehicleType:
    name: str
    agent_class: str  # which route agent drives it: car or heavy
    length_m: float
    emission_class: str  # SUMO HBEFA3 class: fuel consumption for avg_fuel_mlps
    fuel_density_mg_per_ml: float  # petrol for cars, diesel for buses and trucks

    @property
    def accel_mps2(self) -> float:
        return ACTIONS_MPS2[self.agent_class][-1]

    @property
    def decel_mps2(self) -> float:
        return -ACTIONS_MPS2[self.agent_class][0]


VEHICLE_TYPES = {
    "car": VehicleType("car", "car", 5.0, "HBEFA3/PC_G_EU4", 745.0),
    "bus": VehicleType("bus", "heavy", 12.0, "HBEFA3/Bus", 835.0),
    "truck": VehicleType("truck", "heavy", 8.0, "HBEFA3/HDV", 835.0),
}
MIX = {"car": 0.75, "bus": 0.15, "truck": 0.10}  # §4.3.3: the real networks' vehicles
# the option for the artificial networks (Sc1/Sc2/Sc4): passenger cars only. Table 4.2 has one route agent per route there
# (12 / 24 / 32 agents for 12 / 24 / 32 routes), while route agents are per vehicle class (§4.2); §4.3.3 brings in the three
# types for the real network ("in this series of experiments"); the issue and SPEC §3 ask for the mix everywhere (default)
CARS_ONLY = {"car": 1.0}
LS_PERIOD_S = {"car": 4.0, "bus": 10.0, "truck": 15.0}  # LS_const: one car / bus / truck every 4 / 10 / 15 s
ENTRY_SPEED_MPS = 10.0  # §4.3.1
MIN_GAP_M = 2.5  # SUMO's standstill gap, written into every vType (the env adds it back to getLeader's distance)
DRIVER_MODELS = ("IDM", "Krauss")


@dataclass(frozen=True)
class Demand:
    """How vehicles arrive. arrival = "constant": one vehicle every duration_s / n_vehicles seconds, types
    drawn 75/15/10 (CR, MR, LR with noise_sigma_s = 0, 0.5, 1.0), or all cars with cars_only (an option for the
    artificial networks); arrival = "ls": cars, buses and trucks every 4 / 10 / 15 s for duration_s (LS_const, LS_noisy with
    noise_sigma_s = 0.2). The noise is zero-mean Gaussian on every inter-arrival time."""

    n_vehicles: int
    duration_s: float
    arrival: str = "constant"
    noise_sigma_s: float = 0.0
    cars_only: bool = False


def vehicles(demand: Demand, n_routes: int, seed: int) -> dict[str, np.ndarray]:
    """Departure time, vehicle type and route index of every vehicle of one seeded copy, sorted by time."""
    rng = np.random.default_rng(seed)
    if demand.arrival == "constant":
        n = demand.n_vehicles
        gaps = np.full(n, demand.duration_s / n) + rng.normal(0.0, demand.noise_sigma_s, n) * (demand.noise_sigma_s > 0)
        depart = np.cumsum(np.maximum(gaps, 0.1)) - gaps[0]
        mix = CARS_ONLY if demand.cars_only else MIX
        counts = np.round(np.array(list(mix.values())) * n).astype(int)
        counts[0] = n - counts[1:].sum()
        # the same random numbers either way: a cars-only copy has the departures and routes of the mixed copy of its seed
        vtype = rng.permutation(np.repeat(np.array(list(mix)), counts))
    elif demand.arrival == "ls":
        parts_t, parts_v = [], []
        for name, period in LS_PERIOD_S.items():
            n = int(demand.duration_s // period)
            gaps = np.maximum(period + rng.normal(0.0, demand.noise_sigma_s, n) * (demand.noise_sigma_s > 0), 0.1)
            parts_t.append(np.cumsum(gaps) - gaps[0])
            parts_v.append(np.full(n, name))
        depart, vtype = np.concatenate(parts_t), np.concatenate(parts_v)
    else:
        raise ValueError(f"arrival {demand.arrival!r}: expected 'constant' or 'ls'")
    order = np.argsort(depart, kind="stable")
    depart, vtype = np.round(depart[order], 1), vtype[order]
    return {"depart_s": depart, "vtype": vtype, "route": rng.integers(0, n_routes, len(depart))}


def vtypes_xml(model: str, max_speed_mps: float) -> str:
    """Vehicle types for one SUMO driver model; sigma = 0 and speedDev = 0 make every run reproducible."""
    if model not in DRIVER_MODELS:
        raise ValueError(f"driver model {model!r}: expected one of {DRIVER_MODELS}")
    rows = [
        f'  <vType id="{t.name}" vClass="passenger" guiShape="{ {"car": "passenger", "bus": "bus", "truck": "truck"}[t.name] }" '
        f'length="{t.length_m}" minGap="{MIN_GAP_M}" accel="{t.accel_mps2}" decel="{t.decel_mps2}" emergencyDecel="9" '
        f'maxSpeed="{max_speed_mps}" speedDev="0" sigma="0" carFollowModel="{model}" emissionClass="{t.emission_class}"/>\n'
        for t in VEHICLE_TYPES.values()
    ]
    return "<additional>\n" + "".join(rows) + "</additional>\n"


def routes_xml(routes: list[dict], veh: dict[str, np.ndarray]) -> str:
    """Route definitions and vehicles; a vehicle's id is `<route>.<agent class>.<n>` so the env knows its route agent."""
    lines = ["<routes>\n"]
    lines += [f'  <route id="{r["route_id"]}" edges={quoteattr(r["edges"])}/>\n' for r in routes]
    for i, (t, vt, ri) in enumerate(zip(veh["depart_s"], veh["vtype"], veh["route"])):
        rid = routes[ri]["route_id"]
        cls = VEHICLE_TYPES[str(vt)].agent_class
        lines.append(
            f'  <vehicle id="{rid}.{cls}.{i}" type="{vt}" route="{rid}" depart="{t:.1f}" '
            f'departSpeed="{ENTRY_SPEED_MPS}" departLane="best" departPos="base"/>\n'
        )
    lines.append("</routes>\n")
    return "".join(lines)


def write_copy(folder: Path, net_path: Path, routes: list[dict], demand: Demand, max_speed_mps: float, seed: int) -> dict:
    """Write one seeded scenario copy into `folder`; returns its paths and counts."""
    folder.mkdir(parents=True, exist_ok=True)
    veh = vehicles(demand, len(routes), seed)
    (folder / "routes.rou.xml").write_text(routes_xml(routes, veh))
    for model in DRIVER_MODELS:
        (folder / f"vtypes_{model.lower()}.add.xml").write_text(vtypes_xml(model, max_speed_mps))
    counts = {k: int((veh["vtype"] == k).sum()) for k in VEHICLE_TYPES}
    return {
        "net_path": str(net_path),
        "routes_path": str(folder / "routes.rou.xml"),
        "folder": str(folder),
        "n_vehicles": int(len(veh["depart_s"])),
        "last_depart_s": float(veh["depart_s"].max()),
        **{f"n_{k}es" if k.endswith("s") else f"n_{k}s": v for k, v in counts.items()},  # n_cars, n_buses, n_trucks
    }
