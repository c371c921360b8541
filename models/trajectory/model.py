"""A trained trajectory model as one file: per phase a policy (+ selector/posterior) with its modes and goals,
plus the weather cube and bounding box its environment needs — so prediction needs no warehouse tables.

MMIL bundles hold climb, cruise and descent models composed in that order (each phase starts where the
previous one ended); SMIL and BC bundles hold one model for the whole flight (phase "all").
Saved as `<name>.pt` (config + state dicts, torch.save) and `<name>.json` (the config, human-readable).
"""

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from models.trajectory.env import EnvConfig, TrajectoryEnv, WeatherCube, rollout, start_day, to_goal_frame
from models.trajectory.nets import Policy, Scaler, Selector
from models.trajectory.task import Task

FORMAT = "trafficlearn.trajectory.v1"


class TrajectoryModelError(ValueError):
    """A model file that cannot be used (message names the file)."""


@dataclass
class PhaseModel:
    phase: str
    policy: Policy
    selector: Selector | None  # None: one mode per route (BC), no selection
    mode_keys: list[tuple[str, int]]
    goals: torch.Tensor  # (M, 3)
    max_steps: int

    def candidates(self, route: str) -> list[int]:
        return [g for g, (r, _) in enumerate(self.mode_keys) if r == route]

    def mode_label(self, g: int) -> str:
        """Mode g as route/cluster; empty without a selector (BC: one mode per route, nothing was chosen)."""
        route, k = self.mode_keys[g]
        return "" if self.selector is None else f"{route}/{k}"


@dataclass
class Prediction:
    positions: list[np.ndarray]  # per trajectory (n_i, 3) lon, lat, alt_m, including the start point
    modes: np.ndarray  # chosen global mode
    reached: np.ndarray  # goal region reached


class TrajectoryModel:
    def __init__(self, config: dict, phases: list[PhaseModel], cube: WeatherCube, bbox: tuple[float, float, float, float]):
        self.config, self.phases, self.cube, self.bbox = config, phases, cube, bbox
        self.env = TrajectoryEnv(cube, bbox, EnvConfig(dt_s=config["dt_s"]))

    @classmethod
    def from_tasks(cls, config: dict, tasks: list[Task], policies: list[Policy], selectors: list[Selector | None]) -> "TrajectoryModel":
        env = tasks[0].env
        phases = [PhaseModel(t.phase, p, s, t.mode_keys, t.goals, t.max_steps) for t, p, s in zip(tasks, policies, selectors)]
        return cls(config, phases, env.cube, (env.lon0, env.lat0, env.lon1, env.lat1))

    # --- prediction -----------------------------------------------------------------------
    def predict_phase(self, pm: PhaseModel, start: np.ndarray, routes: list[str], start_s: np.ndarray, elapsed0_s: np.ndarray,
                      max_steps: int | None = None) -> tuple[Prediction, np.ndarray]:
        """Roll out every candidate mode of each trajectory's route at once; keep per trajectory the roll-out
        with the highest mean selector/posterior probability of its own mode (§7.4.2 "Mode selection").

        Returns the prediction and, per trajectory, the mean probability of each global mode (renormalised
        over its route's modes) on the chosen roll-out.
        """
        cands = [pm.candidates(r) for r in routes]
        if any(not c for c in cands):
            bad = sorted({r for r, c in zip(routes, cands) if not c})
            raise TrajectoryModelError(f"model {self.config['name']}: no mode for route(s) {', '.join(bad)} "
                                       f"(trained on {', '.join(sorted({k[0] for k in pm.mode_keys}))})")
        traj = np.concatenate([np.full(len(c), i) for i, c in enumerate(cands)])
        mode = torch.as_tensor(np.concatenate(cands))
        start_t = torch.as_tensor(np.array(start, dtype=np.float64))[traj]  # a copy: polars' arrays are read-only (torch warns)
        with torch.no_grad():
            ro = rollout(self.env, lambda o: pm.policy.act(o, mode)[0], start_t, pm.goals[mode],
                         max_steps or pm.max_steps, torch.as_tensor(np.array(elapsed0_s, dtype=np.float64))[traj],
                         torch.as_tensor(start_day(start_s))[traj])
            probs = self._mean_mode_probs(pm, ro, mode, routes, traj)
        own = probs[np.arange(len(traj)), mode.numpy()]
        best = np.array([np.flatnonzero(traj == i)[np.argmax(own[traj == i])] for i in range(len(routes))])  # per trajectory, over ≤ M roll-outs
        steps = ro.steps.numpy()
        pos = ro.positions.numpy()
        return Prediction([pos[: steps[k] + 1, k] for k in best], mode.numpy()[best], ro.reached.numpy()[best]), probs[best]

    def _mean_mode_probs(self, pm: PhaseModel, ro, mode: torch.Tensor, routes: list[str], traj: np.ndarray) -> np.ndarray:
        """Per roll-out, the mean over its live steps of each mode's probability (0 outside the route's modes)."""
        n_modes = len(pm.mode_keys)
        if pm.selector is None:
            return torch.nn.functional.one_hot(mode, n_modes).double().numpy()
        T, B = ro.live.shape
        obs = ro.obs.reshape(T * B, -1)
        logits = pm.selector(obs, pm.policy.act_scaler(to_goal_frame(obs, ro.actions.reshape(T * B, 3)))).view(T, B, -1)
        allowed = torch.zeros(B, n_modes, dtype=torch.bool)
        for i, r in enumerate(routes):
            rows = torch.as_tensor(np.flatnonzero(traj == i))
            allowed[rows[:, None], torch.as_tensor(pm.candidates(r))[None, :]] = True
        p = logits.double().masked_fill(~allowed[None], -torch.inf).softmax(-1)
        live = ro.live[..., None].double()
        return ((p * live).sum(0) / live.sum(0).clamp_min(1)).numpy()

    def mode_probs_on(self, pm: PhaseModel, points: np.ndarray, route: str, start_s: float) -> np.ndarray:
        """Mean selector/posterior probability of each global mode on an observed trajectory (Tables 7.6-7.8)."""
        pos = torch.as_tensor(points, dtype=torch.float64)
        elapsed = torch.arange(len(pos) - 1, dtype=torch.float64) * self.config["dt_s"]
        cand = pm.candidates(route)
        probs = np.zeros(len(pm.mode_keys))
        if pm.selector is None or not cand:
            return probs
        with torch.no_grad():
            out = []
            for g in cand:  # the observation's goal depends on the mode; score each candidate under its own goal
                obs = self.env.observe(pos[:-1], elapsed, pm.goals[g].expand(len(pos) - 1, 3),
                                       torch.full((len(pos) - 1,), float(start_day(start_s)), dtype=torch.float64))
                logit = pm.selector(obs, pm.policy.act_scaler(to_goal_frame(obs, pos[1:] - pos[:-1])))[:, cand]
                out.append(logit.softmax(-1)[:, cand.index(g)].mean().item())
        probs[cand] = np.asarray(out) / max(sum(out), 1e-12)
        return probs

    def predict(self, start: np.ndarray, routes: list[str], start_s: np.ndarray) -> dict[str, tuple[Prediction, np.ndarray]]:
        """Predict whole flights from their first state (positions (B, 3), routes, epoch seconds): the phases
        in order, each starting where and when the previous one ended."""
        out, pos, t = {}, np.asarray(start, dtype=np.float64), np.asarray(start_s, dtype=np.float64)
        for pm in self.phases:
            pred, probs = self.predict_phase(pm, pos, routes, t, np.zeros(len(pos)))
            out[pm.phase] = (pred, probs)
            pos = np.stack([p[-1] for p in pred.positions])
            t = t + np.array([len(p) - 1 for p in pred.positions]) * self.config["dt_s"]
        return out

    # --- files ----------------------------------------------------------------------------
    def save(self, path: Path) -> Path:
        from warehouse.artifacts import write_bytes_atomic
        import io

        payload = {
            "format": FORMAT, "config": self.config, "bbox": list(self.bbox),
            "cube": {"tensor": self.cube.cube, "alt_m": self.cube.alt_m.tolist(),
                     "bbox": [self.cube.lon0, self.cube.lat0, self.cube.lon1, self.cube.lat1]},
            "phases": [{
                "phase": pm.phase, "mode_keys": [list(k) for k in pm.mode_keys], "goals": pm.goals, "max_steps": pm.max_steps,
                "policy": pm.policy.state_dict(), "selector": None if pm.selector is None else pm.selector.state_dict(),
            } for pm in self.phases],
        }
        buf = io.BytesIO()
        torch.save(payload, buf)
        write_bytes_atomic(path, buf.getvalue())
        cfg = {**self.config, "bbox": list(self.bbox), "phases": [{"phase": pm.phase, "modes": [list(k) for k in pm.mode_keys],
               "goals_lon_lat_alt_m": pm.goals.tolist(), "max_steps": pm.max_steps} for pm in self.phases]}
        write_bytes_atomic(path.with_suffix(".json"), json.dumps(cfg, indent=1).encode())
        return path

    @classmethod
    def load(cls, path: str | Path) -> "TrajectoryModel":
        path = Path(path)
        if not path.is_file():
            raise TrajectoryModelError(f"model file {path}: not found")
        try:
            payload = torch.load(path, map_location="cpu", weights_only=True)
        except Exception as exc:  # noqa: BLE001 — any unpickling failure means "not a model file"
            raise TrajectoryModelError(f"model file {path}: not a trajectory model ({type(exc).__name__})") from None
        if not isinstance(payload, dict) or payload.get("format") != FORMAT:
            raise TrajectoryModelError(f"model file {path}: not a trajectory model (expected format {FORMAT})")
        try:
            cube = WeatherCube.__new__(WeatherCube)
            cube.cube, cube.alt_m = payload["cube"]["tensor"], np.asarray(payload["cube"]["alt_m"])
            cube.lon0, cube.lat0, cube.lon1, cube.lat1 = payload["cube"]["bbox"]
            phases = []
            for ph in payload["phases"]:
                n_modes = len(ph["mode_keys"])
                sd = ph["policy"]
                obs_s, act_s = (Scaler(sd[f"{k}.mean"], sd[f"{k}.std"]) for k in ("obs_scaler", "act_scaler"))
                policy = Policy(n_modes, obs_s, act_s)
                policy.load_state_dict(sd)
                selector = None
                if ph["selector"] is not None:
                    selector = Selector(n_modes, obs_s)
                    selector.load_state_dict(ph["selector"])
                phases.append(PhaseModel(ph["phase"], policy.eval(), selector, [tuple(k) for k in ph["mode_keys"]],
                                         ph["goals"], int(ph["max_steps"])))
            return cls(payload["config"], phases, cube, tuple(payload["bbox"]))
        except (KeyError, RuntimeError, TypeError) as exc:
            raise TrajectoryModelError(f"model file {path}: damaged ({type(exc).__name__}: {str(exc).splitlines()[0][:120]})") from None
