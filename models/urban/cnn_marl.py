"""Chapter 3's variant: speed actions, a DQN over the individual state + a CNN/DDQN over the collision matrix.

One route agent per route x vehicle class, as in col-MARL (the training loop, replay buffers, DDQN update and
parallel episodes are models.urban.col_marl's; this file holds what differs):

* Actions (§3.4.2): a target speed A = {15, 20, 25, 30} m/s, set with `setSpeed`; SUMO's low-level controller
  reaches it at the vehicle type's acceleration / deceleration (speed mode 38 = 32 + max accel + max decel:
  still no safe speed and no right of way).
* State (§3.4.1): s1 = [vel, inter_dist, fveh_dist, fveh_vel] (scaled as in models.urban.env) and s2 = the
  *collision matrix* of the next junction, a G x G grid over the junction's square (G = 6 as in Fig 3.2; the
  thesis sizes it by the junction's lanes, a fixed grid works for any real junction). The ego vehicle's path
  through the junction (straight from its lane's end to its next road's start, crossed at its current speed)
  fills its cells with -1; a cell of that path that another vehicle is predicted to occupy at the same time
  (every other vehicle assumed to go straight on at constant speed, §3.4.1) becomes -5; every other cell counts
  the other vehicles' predicted visits while the ego vehicle crosses.
* Reward (Eq 3.1-3.3): ±L at the goal / on a collision; C = -1 if the matrix predicts a collision (a -5 cell),
  else 1; front vehicle farther than safe_dist = 50 m: C β1 vel/vel_max; nearer: -(β2 + vel/vel_max)(safe_dist -
  fveh_dist) with β2 = 1 (C = 1) or 2 (C = -1); β1 = 3, vel_max = 30 m/s.
* Q (Eq 3.4): Q(s, a) = μ Q_DQN(s1, a) + (1 - μ) Q_DDQN(CNN(s2), a), μ = 0.5; DQN: 4 -> 100 ReLU -> 4; CNN: 8
  filters 3 x 3, ReLU, 2 x 2 max-pool -> 200 ReLU -> 4 (§3.5.3). Both nets are trained together on the DDQN
  loss of the combined Q, from one replay buffer of 15,000 transitions per agent that holds (s1, s2) — the
  thesis's two aligned buffers.
"""

import functools
from pathlib import Path

import gymnasium
import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from models.urban import kernels
from models.urban.env import INTER_TIME_S, UrbanParallelEnv
from models.urban.network import read_net

# --- hyperparameters (§3.4-3.5.3) ---------------------------------------------------------------
SPEEDS_MPS = (15.0, 20.0, 25.0, 30.0)
SPEED_MODE_LIMITED = 38  # 32 (no safe speed, no right of way) + regard max acceleration (2) and deceleration (4)
MU = 0.5  # Eq 3.4
DQN_HIDDEN, CNN_FILTERS, CNN_KERNEL, CNN_HIDDEN = 100, 8, 3, 200
GRID = 6  # collision matrix GRID x GRID
SAMPLES = 8  # points of the ego vehicle's crossing at which the others' positions are predicted
PATH, CONFLICT = -1.0, -5.0  # cell values of §3.4.1
SAFE_DIST_M, BETA1 = 50.0, 3.0  # Eq 3.2, 3.3
VEL_MAX_MPS = max(SPEEDS_MPS)
BUFFER_SIZE = 15_000  # per route agent (§3.5.3)
GRADIENT_STEPS_PER_EPISODE = 10  # not in the thesis; its CNN steps cost ~6x col-MARL's, and 10 is collision-free on Sc1
INDIVIDUAL_DIM = 4
STATE_DIM = INDIVIDUAL_DIM + GRID * GRID
SIDE = GRID - CNN_KERNEL + 1  # pixels per side after the convolution


def _conv_scatter() -> torch.Tensor:
    """[cell, k, pixel] = 1 where grid cell `cell` is entry k (of CNN_KERNEL²) of output pixel `pixel`'s window."""
    i, j, di, dj = np.meshgrid(*[np.arange(SIDE)] * 2, *[np.arange(CNN_KERNEL)] * 2, indexing="ij")
    out = torch.zeros(GRID * GRID, CNN_KERNEL**2, SIDE * SIDE)
    out[((i + di) * GRID + j + dj).ravel(), (di * CNN_KERNEL + dj).ravel(), (i * SIDE + j).ravel()] = 1.0
    return out


_CONV_SCATTER = _conv_scatter()


# --- collision matrix ---------------------------------------------------------------------------


class JunctionGeometry:
    """Per junction its centre and half-size; per lane its end point and end direction; per edge its start."""

    def __init__(self, net_path: str):
        net = read_net(Path(net_path))
        nodes = net.getNodes()  # the order of models.urban.sim.NetIndex: same junction indices
        self.centre = np.array([n.getCoord()[:2] for n in nodes], float)
        self.half_m = np.array([max(np.abs(np.array(n.getShape())[:, :2] - c).max() if n.getShape() else 0.0, 5.0)
                                for n, c in zip(nodes, self.centre)])
        self.lane_end, self.lane_dir, self.edge_start = {}, {}, {}
        lanes = [ln for e in net.getEdges(withInternal=True) for ln in e.getLanes()]
        for ln in lanes:
            shape = np.array(ln.getShape())[:, :2]
            d = shape[-1] - shape[-2]
            self.lane_end[ln.getID()] = shape[-1]
            self.lane_dir[ln.getID()] = d / max(np.linalg.norm(d), 1e-6)
        for e in net.getEdges():
            self.edge_start[e.getID()] = np.array(e.getLanes()[0].getShape()[0][:2])


@functools.lru_cache(maxsize=8)
def geometry(net_path: str) -> JunctionGeometry:
    return JunctionGeometry(net_path)


def collision_matrix(junction, entry, exit_, xy, direction, dist_m, speed, centre, half_m):
    """Collision matrix of every vehicle with a junction ahead, vectorised over (ego, other, time sample).

    junction [n] (-1: none ahead), entry/exit_ [n, 2]: the ego's crossing segment, xy/direction [n, 2]: where
    everyone is and the way it goes, dist_m/speed [n]; centre/half_m per junction. Returns [n, GRID, GRID]."""
    n = len(junction)
    out = np.zeros((n, GRID, GRID), np.float32)
    ego = np.flatnonzero(junction >= 0)
    if not len(ego):
        return out
    v = np.maximum(speed, 1.0)
    frac = np.linspace(0.0, 1.0, SAMPLES)
    t_in = dist_m[ego] / v[ego]
    cross_s = np.linalg.norm(exit_[ego] - entry[ego], axis=1) / v[ego]
    t = t_in[:, None] + cross_s[:, None] * frac  # [e, k] when the ego is at each point of its path
    ego_xy = entry[ego, None] + (exit_[ego] - entry[ego])[:, None] * frac[:, None]  # [e, k, 2]
    other_xy = xy[None, :, None] + (speed[None, :, None, None] * t[:, None, :, None]) * direction[None, :, None]  # [e, o, k, 2]
    j = junction[ego]
    cell = lambda p, c, h: np.floor((p - c + h) / (2 * h) * GRID).astype(int)  # noqa: E731
    ego_cell = cell(ego_xy, centre[j][:, None], half_m[j][:, None, None])  # [e, k, 2]
    other_cell = cell(other_xy, centre[j][:, None, None], half_m[j][:, None, None, None])  # [e, o, k, 2]
    # others: vehicles approaching or inside the same junction, not the ego itself
    near = (junction[None, :] == j[:, None]) & (np.arange(n)[None, :] != ego[:, None])
    inside = ((other_cell >= 0) & (other_cell < GRID)).all(axis=3) & near[:, :, None]
    e_idx, o_idx, k_idx = np.nonzero(inside)
    np.add.at(out, (ego[e_idx], other_cell[e_idx, o_idx, k_idx, 0], other_cell[e_idx, o_idx, k_idx, 1]), 1.0)
    on_grid = ((ego_cell >= 0) & (ego_cell < GRID)).all(axis=2)
    pe, pk = np.nonzero(on_grid)
    out[ego[pe], ego_cell[pe, pk, 0], ego_cell[pe, pk, 1]] = PATH
    # a path cell another vehicle is predicted in within INTER_TIME_S of the ego's own time there: [e, o, k_ego, k_other]
    close = np.abs(t[:, :, None] - t[:, None, :]) <= INTER_TIME_S  # [e, k, k']
    hit = (other_cell[:, :, None] == ego_cell[:, None, :, None]).all(axis=4) & inside[:, :, None] & close[:, None]
    ce, ck = np.nonzero(hit.any(axis=(1, 3)) & on_grid)
    out[ego[ce], ego_cell[ce, ck, 0], ego_cell[ce, ck, 1]] = CONFLICT
    return out


def reward(speed: np.ndarray, fveh_dist: np.ndarray, conflict: np.ndarray) -> np.ndarray:
    """Eq 3.2-3.3 (non-terminal), C = -1 when the collision matrix predicts a collision."""
    fv = speed / VEL_MAX_MPS
    c = np.where(conflict, -1.0, 1.0)
    near = (fveh_dist >= 0) & (fveh_dist < SAFE_DIST_M)
    beta2 = np.where(conflict, 2.0, 1.0)
    return np.where(near, -(beta2 + fv) * (SAFE_DIST_M - fveh_dist), c * BETA1 * fv)


class Ch3Env(UrbanParallelEnv):
    """The env of models.urban.env with chapter 3's actions, state and reward (same PettingZoo API)."""

    def __init__(self, files, variant: str = "ch3", sumo_seed: int = 0, record: bool = False, leader_guard: bool = False, shield: bool = False):
        if shield:
            raise ValueError("chapter 3's env has no safety layer (shield=True is for the col/ind variants)")
        super().__init__(files, "ind", sumo_seed, record, leader_guard=False)  # its own speed mode below, IDM vehicle types
        self.variant, self.speed_mode = "ch3", SPEED_MODE_LIMITED
        self.positions = True  # the collision matrix needs where everyone is
        self._obs_space = gymnasium.spaces.Box(-np.inf, np.inf, (STATE_DIM,), np.float32)
        self._act_space = gymnasium.spaces.Discrete(len(SPEEDS_MPS))
        self.geo = geometry(files.net)

    def _apply(self, ids: list, action: np.ndarray, speed: np.ndarray) -> None:
        for v, a in zip(ids, action):
            self.sim.ls.vehicle.setSpeed(v, SPEEDS_MPS[a])

    def _state_reward(self, snap, route):
        _, junction, internal, dist, _, last_road = kernels.lane_facts(*self._lane_args(snap, route))
        geo = self.geo
        xy = np.column_stack([snap.x, snap.y])
        entry = np.where(internal[:, None], xy, np.array([geo.lane_end.get(ln, (0.0, 0.0)) for ln in snap.lane]).reshape(-1, 2))
        direction = np.array([geo.lane_dir.get(ln, (0.0, 0.0)) for ln in snap.lane]).reshape(-1, 2)
        exit_ = np.array([self._exit_point(v, k, e) for v, k, e in zip(snap.ids, snap.route_index, entry)]).reshape(-1, 2)
        m = collision_matrix(junction, entry, exit_, xy, direction, dist, snap.speed, geo.centre, geo.half_m)
        conflict = (m == CONFLICT).any(axis=(1, 2))
        state = np.column_stack([self.individual_state(snap, dist), m.reshape(len(m), -1)]).astype(np.float32)
        return state, reward(snap.speed, snap.leader_dist, conflict), last_road

    def _exit_point(self, vehicle: str, route_index: int, entry: np.ndarray) -> np.ndarray:
        """Start of the road after the junction ahead (the route index stays on the last normal edge inside a junction)."""
        edges = self.routes[vehicle.rsplit(".", 2)[0]]
        return self.geo.edge_start[edges[route_index + 1]] if route_index + 1 < len(edges) else entry


# --- Q-network (Eq 3.4), weights stacked per route agent as in models.urban.col_marl --------------------------


def q_forward(p: dict, x: torch.Tensor) -> torch.Tensor:
    """x [agent, batch, STATE_DIM] -> Q [agent, batch, action] = μ Q_DQN(s1) + (1 - μ) Q_DDQN(CNN(s2))."""
    a, b, _ = x.shape
    s1, s2 = x[..., :INDIVIDUAL_DIM], x[..., INDIVIDUAL_DIM:]
    q1 = torch.baddbmm(p["d_b2"][:, None], torch.relu(torch.baddbmm(p["d_b1"][:, None], s1, p["d_w1"])), p["d_w2"])
    # the 3 x 3 convolution is a linear map of the 36 cells: one matrix product with the agent's filters scattered into
    # a [36, pixel x filter] matrix (with F.unfold, which loops over the batch, and amax the step was 2.2x slower)
    kernel = torch.einsum("ckp,akf->acpf", _CONV_SCATTER, p["c_w"]).flatten(2)
    conv = torch.relu(torch.baddbmm(p["c_b"].repeat(1, SIDE * SIDE)[:, None], s2, kernel))
    # 2 x 2 max-pool over the channels-last [pixel, filter] layout (max_pool2d keeps the argmax: a cheap backward)
    pooled = F.max_pool2d(conv.reshape(a * b, SIDE, SIDE, CNN_FILTERS).permute(0, 3, 1, 2), 2).permute(0, 2, 3, 1).reshape(a, b, -1)
    h = torch.relu(torch.baddbmm(p["c_b1"][:, None], pooled, p["c_w1"]))
    q2 = torch.baddbmm(p["c_b2"][:, None], h, p["c_w2"])
    return MU * q1 + (1 - MU) * q2


class RouteAgentsDQNCNN(nn.Module):
    """Q(s, ·) of every route agent (DQN + CNN/DDQN), weights stacked as [agent, ...]."""

    def __init__(self, n_agents: int, state_dim: int, generator: torch.Generator):
        super().__init__()
        assert state_dim == STATE_DIM, state_dim
        n_act, pooled = len(SPEEDS_MPS), CNN_FILTERS * ((GRID - CNN_KERNEL + 1) // 2) ** 2

        def init(*shape, fan_in):  # PyTorch's default Linear / Conv2d initialisation, per agent
            bound = 1.0 / np.sqrt(fan_in)
            return nn.Parameter((torch.rand(n_agents, *shape, generator=generator) * 2 - 1) * bound)

        k2 = CNN_KERNEL**2
        self.p = nn.ParameterDict({
            "d_w1": init(INDIVIDUAL_DIM, DQN_HIDDEN, fan_in=INDIVIDUAL_DIM), "d_b1": init(DQN_HIDDEN, fan_in=INDIVIDUAL_DIM),
            "d_w2": init(DQN_HIDDEN, n_act, fan_in=DQN_HIDDEN), "d_b2": init(n_act, fan_in=DQN_HIDDEN),
            "c_w": init(k2, CNN_FILTERS, fan_in=k2), "c_b": init(CNN_FILTERS, fan_in=k2),
            "c_w1": init(pooled, CNN_HIDDEN, fan_in=pooled), "c_b1": init(CNN_HIDDEN, fan_in=pooled),
            "c_w2": init(CNN_HIDDEN, n_act, fan_in=CNN_HIDDEN), "c_b2": init(n_act, fan_in=CNN_HIDDEN),
        })

    def forward(self, x: torch.Tensor, agents: slice = slice(None)) -> torch.Tensor:
        return q_forward({k: v[agents] for k, v in self.p.items()}, x)


def q_values(params: dict[str, np.ndarray], states: np.ndarray, agent_idx: np.ndarray) -> np.ndarray:
    """Q of each vehicle under its own route agent (rollout workers; params as saved by numpy_params)."""
    p = {k.removeprefix("p."): torch.from_numpy(v[agent_idx]) for k, v in params.items()}
    with torch.no_grad():
        return q_forward(p, torch.from_numpy(states[:, None, :]))[:, 0].numpy()
