"""Helpers of the urban tests (imported as a plain module: pytest puts tests/urban on sys.path)."""

from pathlib import Path

import numpy as np

from models.urban.network import enumerate_routes
from models.urban.scenarios import Demand, vtypes_xml, write_copy
from models.urban.sim import ScenarioFiles


def make_copy(folder: Path, net: Path, n_vehicles: int = 30, duration_s: float = 120.0, seed: int = 0, vmax: float = 40.0):
    routes = enumerate_routes(net, 12, 0)
    info = write_copy(folder, net, routes, Demand(n_vehicles, duration_s), vmax, seed)
    return ScenarioFiles(str(net), info["routes_path"], info["folder"], info["last_depart_s"], vmax), routes


def hand_copy(folder: Path, net: Path, routes_xml: str, last_depart_s: float = 0.0) -> ScenarioFiles:
    """A scenario copy from hand-written routes and vehicles (the body of a <routes> file) with the env's vehicle types."""
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "routes.rou.xml").write_text(f"<routes>\n{routes_xml}</routes>\n")
    for model in ("IDM", "Krauss"):
        (folder / f"vtypes_{model.lower()}.add.xml").write_text(vtypes_xml(model, 40.0))
    return ScenarioFiles(str(net), str(folder / "routes.rou.xml"), str(folder), last_depart_s, 40.0)


def crossing_copy(folder: Path, net: Path, turn: bool = False) -> ScenarioFiles:
    """Two cars on crossing routes of Sc1, same entry time, same distance to the junction: if both hold
    their speed they meet in the middle of the junction. turn=True: one car alone, turning left."""
    cars = ('  <vehicle id="r001.car.0" type="car" route="r001" depart="0" departSpeed="10" departPos="base"/>\n' if turn else
            '  <vehicle id="r000.car.0" type="car" route="r000" depart="0" departSpeed="10" departPos="base"/>\n'
            '  <vehicle id="r001.car.1" type="car" route="r001" depart="0" departSpeed="10" departPos="base"/>\n')
    second = "bottom0A0 A0left0" if turn else "bottom0A0 A0top0"
    return hand_copy(folder, net, f'  <route id="r000" edges="left0A0 A0right0"/>\n  <route id="r001" edges="{second}"/>\n{cars}')


def constant_policy(agents: list, action: int) -> dict:
    """col-MARL weights whose every route agent picks `action` (index of Table 4.1) whatever the state."""
    n = len(agents)
    b2 = np.zeros((n, 5), np.float32)
    b2[:, action] = 1.0
    return {"w1": np.zeros((n, 6, 128), np.float32), "b1": np.zeros((n, 128), np.float32), "w2": np.zeros((n, 128, 5), np.float32), "b2": b2}
