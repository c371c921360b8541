"""A rerun recording (.rrd) replaying one evaluation episode: the network's lanes, every vehicle at 1 s
on the `sim_time` timeline coloured by its route agent, collisions marked by red rings.

Open with `rerun <file>.rrd`. Written offline into a file sink (temp file + rename), no viewer spawned.
"""

import uuid
from pathlib import Path

import numpy as np
import polars as pl
import rerun as rr

from models.urban.network import read_net
from warehouse.storage import replace_atomically


def _agent_colors(agents: list[str]) -> dict[str, np.ndarray]:
    """A stable colour per route agent (golden-angle hues)."""
    from matplotlib.colors import hsv_to_rgb

    return {a: (hsv_to_rgb([(i * 0.618) % 1.0, 0.75, 0.95]) * 255).astype(np.uint8) for i, a in enumerate(sorted(agents))}


def write_episode_recording(traj: pl.DataFrame, net_path: str, path: Path, title: str) -> Path:
    """traj: urban_trajectories rows of ONE scenario and method."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    net = read_net(net_path)
    lanes = [np.array(ln.getShape(), np.float32) for e in net.getEdges() for ln in e.getLanes()]
    colors = _agent_colors(traj["agent"].unique().to_list())

    def write(tmp: str) -> None:
        rec = rr.RecordingStream("trafficlearn_urban", recording_id=uuid.uuid4())
        rec.save(tmp)
        rec.send_recording_name(title)
        rec.log("network/lanes", rr.LineStrips2D(lanes, colors=[[150, 150, 150]], radii=0.8), static=True)
        rec.log("description", rr.TextDocument(f"{title}\nVehicles coloured by route agent; red rings: collisions (last position)."), static=True)
        for (t,), g in traj.sort("t").group_by("t", maintain_order=True):
            rec.set_time("sim_time", duration=float(t))
            rec.log(
                "vehicles",
                rr.Points2D(g.select("x", "y").to_numpy(), colors=np.stack([colors[a] for a in g["agent"]]), radii=2.5,
                            labels=g["vehicle_id"].to_list()),
            )
        last = traj.filter(pl.col("collided")).sort("t").group_by("vehicle_id").agg(pl.col("t", "x", "y").last())
        for row in last.iter_rows(named=True):
            rec.set_time("sim_time", duration=float(row["t"]))
            rec.log(f"collisions/{rr.escape_entity_path_part(row['vehicle_id'])}", rr.Points2D([[row["x"], row["y"]]], colors=[[255, 0, 0]], radii=6.0))
        rec.flush()
        rec.disconnect()

    return replace_atomically(path, write, ".rrd")
