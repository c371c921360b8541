"""Road networks for the urban system, built with the real SUMO tools of the eclipse-sumo wheel.

Every network is made *unsignalized*: no traffic lights and no priority roads, every junction of type
`right_before_left` (thesis §4.3.1). `right_before_left` rather than `unregulated` because SUMO never
checks collisions inside `unregulated` junctions (and `getJunctionFoes` crashes on them); the controlled
vehicles ignore the right-of-way rule anyway (their speed modes, models.urban.sim's and cnn_marl's, leave the
right-of-way bit off), the SUMO baselines (IDM, Krauss) obey it.
"""

import gzip
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import sumolib

# the only junction types of an unsignalized network: dead ends are the outer ends of its entry and exit roads
SIGNAL_FREE_TYPES = {"right_before_left", "dead_end"}
# SUMO cannot insert a vehicle at the 10 m/s entry speed on a shorter entry road (its length, gap and braking distance
# before the junction): its vehicles would wait outside the network all episode (Monaco's 7.5-19.9 m entries; on a test
# grid buses failed on 27.8 m and entered on 32.8 m). Sc1 and the bundled Bologna network have no entry under 53 m.
MIN_ENTRY_ROAD_M = 35.0


class UrbanInputError(ValueError):
    """A network, OSM, route or scenario file that cannot be used; the message names the file and the problem."""


def run_tool(tool: str, args: list[str], what: Path) -> None:
    """Run a SUMO command-line tool; a failure becomes one UrbanInputError line naming `what`."""
    proc = subprocess.run([sumolib.checkBinary(tool), *map(str, args)], capture_output=True, text=True)
    if proc.returncode != 0:
        errors = [ln for ln in proc.stderr.splitlines() if ln.startswith("Error")] or proc.stderr.splitlines()[-1:] or ["?"]
        raise UrbanInputError(f"{what}: {tool} failed: {errors[0]}")


def artificial_network(n_intersections: int, out: Path, road_length_m: float = 200.0, speed_mps: float = 40.0) -> Path:
    """Sc1/Sc2/Sc4 (Fig 4.2): a 1x1, 2x1 or 2x2 grid of four-arm intersections with attached arms,
    one lane per direction, every junction right_before_left (8 / 14 / 24 roads as in Table 4.2)."""
    grids = {1: (1, 1), 2: (2, 1), 4: (2, 2)}
    if n_intersections not in grids:
        raise UrbanInputError(f"artificial network: {n_intersections} intersections; expected one of {sorted(grids)}")
    nx, ny = grids[n_intersections]
    run_tool(
        "netgenerate",
        ["--grid", "--grid.x-number", nx, "--grid.y-number", ny, "--grid.length", road_length_m,
         "--grid.attach-length", road_length_m, "-j", "right_before_left", "-S", speed_mps,
         "--no-turnarounds", "true", "--no-warnings", "true", "-o", out],
        out,
    )
    return out


def read_net(path: Path, internal: bool = False) -> sumolib.net.Net:
    """sumolib network (with the lanes inside the junctions if `internal`), or one UrbanInputError line if the file is
    missing or not a SUMO network."""
    path = Path(path)
    if not path.exists():
        raise UrbanInputError(f"{path}: network file not found")
    try:
        net = sumolib.net.readNet(str(path), withInternal=internal)
    except Exception as e:  # sumolib raises bare SAX/XML errors
        raise UrbanInputError(f"{path}: not a readable SUMO .net.xml ({type(e).__name__}: {e})") from None
    if not net.getEdges():
        raise UrbanInputError(f"{path}: SUMO network without edges")
    return net


def unsignalize(src: Path, out: Path, speed_mps: float) -> Path:
    """Patch an existing SUMO network: every junction right_before_left, traffic lights dropped and
    every road's speed limit set to `speed_mps` so that the SUMO drivers may go as fast as the agents.
    (`--tls.discard-loaded` alone would leave priority junctions.)"""
    net = read_net(src)
    with tempfile.TemporaryDirectory() as tmp:
        nodes, edges = Path(tmp) / "patch.nod.xml", Path(tmp) / "patch.edg.xml"
        nodes.write_text(
            "<nodes>\n"
            + "".join(f'  <node id="{n.getID()}" type="right_before_left"/>\n' for n in net.getNodes() if n.getType() != "dead_end")
            + "</nodes>\n"
        )
        edges.write_text("<edges>\n" + "".join(f'  <edge id="{e.getID()}" speed="{speed_mps}"/>\n' for e in net.getEdges()) + "</edges>\n")
        run_tool(
            "netconvert",
            ["-s", src, "--node-files", nodes, "--edge-files", edges, "--tls.discard-loaded", "true",
             "--no-turnarounds", "true", "--no-warnings", "true", "-o", out],
            src,
        )
    return out


def osm_network(osm: Path, out: Path, speed_mps: float = 30.0) -> Path:
    """Any OpenStreetMap extract (.osm or .osm.gz) -> unsignalized SUMO network of its car roads."""
    osm = Path(osm)
    if not osm.exists():
        raise UrbanInputError(f"{osm}: OSM file not found")
    with tempfile.TemporaryDirectory() as tmp:
        raw = Path(tmp) / "osm.net.xml"
        run_tool(
            "netconvert",
            ["--osm-files", osm, "--geometry.remove", "--roundabouts.guess", "--junctions.join",
             "--tls.discard-loaded", "--tls.discard-simple", "--keep-edges.by-vclass", "passenger",
             "--remove-edges.isolated", "--no-turnarounds", "--no-warnings", "true", "-o", raw],
            osm,
        )
        return unsignalize(raw, out, speed_mps)


def sumo_network(src: Path, out: Path, speed_mps: float = 30.0) -> Path:
    """A user's SUMO network (.net.xml or .net.xml.gz) -> unsignalized copy."""
    src = Path(src)
    if src.suffix == ".gz":
        with tempfile.TemporaryDirectory() as tmp:
            plain = Path(tmp) / src.stem
            try:
                with gzip.open(src) as f, open(plain, "wb") as g:
                    shutil.copyfileobj(f, g)
            except (OSError, EOFError) as e:
                raise UrbanInputError(f"{src}: not a gzip file ({e})") from None
            return unsignalize(plain, out, speed_mps)
    return unsignalize(src, out, speed_mps)


@dataclass(frozen=True)
class JunctionCensus:
    junctions: int  # not counting dead ends
    traffic_lights: int
    types: dict


def junction_census(path: Path) -> JunctionCensus:
    """What a network's junctions are: the tests and the networks_unsignalized check assert no traffic lights and no priority junctions."""
    net = read_net(path)
    types: dict[str, int] = {}
    for n in net.getNodes():
        types[n.getType()] = types.get(n.getType(), 0) + 1
    return JunctionCensus(
        junctions=sum(v for k, v in types.items() if k != "dead_end"),
        traffic_lights=len(net.getTrafficLights()),
        types=types,
    )


def enumerate_routes(path: Path, max_routes: int, seed: int, max_length_m: float = float("inf")) -> list[dict]:
    """Route agents' routes: shortest paths between the network's entry and exit roads that cross at least
    one junction. An entry road starts at a node no other road leads into (a fringe), an exit road ends at
    one no other road leaves; U-turns back onto the same street and entry roads shorter than MIN_ENTRY_ROAD_M are excluded. If there are more pairs than
    `max_routes`, a seeded sample keeps them (Table 4.2: 12 / 24 / 32 routes for Sc1 / Sc2 / Sc4).
    Routes longer than `max_length_m` are left out (the demo profile keeps the real network's routes short)."""
    net = read_net(path)
    edges = [e for e in net.getEdges() if e.allows("passenger") and e.getFunction() == ""]

    # the reverse of an edge (same street, other direction) does not count as another road
    sources = [e for e in edges if all(x.getFromNode() is e.getToNode() for x in e.getFromNode().getIncoming())
               and e.getLength() >= MIN_ENTRY_ROAD_M]
    sinks = [e for e in edges if all(x.getToNode() is e.getFromNode() for x in e.getToNode().getOutgoing())]
    routes = []
    for s in sources:
        for t in sinks:
            if s.getID() == t.getID() or s.getFromNode() is t.getToNode():
                continue
            path_edges, _ = net.getShortestPath(s, t, vClass="passenger")
            if path_edges and len(path_edges) >= 2 and sum(e.getLength() for e in path_edges) <= max_length_m:
                routes.append(path_edges)
    if not routes:
        raise UrbanInputError(f"{path}: no route between entry roads of >= {MIN_ENTRY_ROAD_M:.0f} m and exit roads crosses a junction")
    rng = np.random.default_rng(seed)
    if len(routes) > max_routes:
        routes = [routes[i] for i in sorted(rng.choice(len(routes), max_routes, replace=False))]
    return [
        {
            "route_id": f"r{i:03d}",
            "edges": " ".join(e.getID() for e in r),
            "length_m": float(sum(e.getLength() for e in r)),
            "n_junctions": len(r) - 1,
            "origin_edge": r[0].getID(),
            "destination_edge": r[-1].getID(),
        }
        for i, r in enumerate(routes)
    ]
