"""AppLearn: apprenticeship learning (inverse RL) for aircraft trajectory prediction, thesis chapter 6, Algorithm 7.

One file, CleanRL style: hyperparameters, state features, the max-margin QP, the DQN, the training loop of
Algorithm 7 and the saved model, in that order. The equations, as in §6.4:

    φ_pos,k(s)   = exp(-β_pos   ‖p - μ_k^pos‖²)      p = (lon, lat); 20 centres along the centroid trajectory (6.2)
    φ_meteo,k(s) = exp(-β_meteo ‖v - μ_k^meteo‖²)    v = z-scored (T, u, v); 20 K-means centres         (6.3)
    R_w(s)       = wᵀ φ(s)                                                                              (6.5)
    μ(π)         = E[Σ_t γᵗ φ(s_t)]          (μ(π_E): mean over the expert flights)                    (6.6, 6.7)
    w            = argmax_{w,t} t  s.t. wᵀμ(π_E) ≥ wᵀμ(π_j) + t for every policy j so far, ‖w‖₂ ≤ 1
                   (the max-margin QP of Abbeel & Ng 2004; a second-order cone program, solved by CLARABEL)
    DQN          : L(θ) = E[(Σ_{j<n} γʲ r_{t+j} + γⁿ (1 - done) max_a' Q_θ⁻(s_{t+n}, a') - Q_θ(s_t, a_t))²]   (n-step)
                   r = c · (R_w(s') + r_aug(s') + Φ(s') - Φ(s)); with advantage learning the target also loses
                   α (max_a Q_θ⁻(s_t, a) - Q_θ⁻(s_t, a_t))  (Baird 1999: widens the gaps between the headings' Q-values)

r_aug is the reward augmentation of §6.5.2: a large bonus on reaching the destination, a large penalty on
leaving the box or hitting the step limit. The environment is models.trajectory.heading_env (Eq 6.4).

Additions beyond the thesis, each with a switch among the hyperparameters (docs/applearn.md says why and
what each measured): φ gets a route feature φ_route(s) = exp(-d²/2σ²), d the distance to the experts'
centroid route and σ the experts' RMS distance to it (Eq 6.2's centres lie ~50-100 km apart along the route
with RBF widths to match, so φ_pos cannot tell a point 20 km off the route from one on it); a progress reward
Φ(s') - Φ(s), Φ(s) = -(distance to the goal along the route) / step (Ng et al.'s shaping without the γ on
Φ(s'), see `progress_reward`), which pays every step's progress at once; n-step returns; a step reward ≤ 0;
the wider fan of headings (heading_env.fit_geometry); the IRL step's policy with the best greedy success on
the training flights is returned; advantage learning in the DQN target; and, in training only, a quarter of
the episodes start along the route and 15 % on its final approach, and an episode fails as soon as it leaves a
corridor around the route or passes the goal.

Choices the thesis leaves open or that deviate from it are commented at their parameters (gamma,
success_reward, failure_reward, reward_scale, feature_gamma, start_anywhere_fraction). The main deviation, on by default
(`goal_offset_input`): the Q-network also sees the offset to the goal, scaled by the box size. φ alone
locates the aircraft only to within one RBF width (~50 km), too coarse to aim at the 5 km goal disc; the
reward and the IRL step still use φ only.
"""

import io
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np
import polars as pl
import torch

from models.trajectory.heading_env import (
    OUT_OF_BOX,
    RUNNING,
    SUCCESS,
    WEATHER_COLUMNS,
    AltitudeNet,
    HeadingEnv,
    HeadingGeometry,
    ModelFileError,
    StartStates,
    expert_observations,
    fit_altitude_net,
    fit_geometry,
    resample_flights,
)


# ------------------------------------------------------------------------------------------ hyperparameters
@dataclass(frozen=True)
class AppLearnParams:
    """Defaults = the thesis's budgets (§6.4.1, §6.5.2); PROFILES["demo"] shrinks the budgets only."""

    n_pos_centres: int = 20  # L_pos
    n_meteo_centres: int = 20  # L_meteo
    n_headings: int = 4  # L_a, the discrete actions
    heading_coverage: float = 0.95  # the headings' fan spans this central share of the expert step directions
    goal_radius_km: float = 5.0  # success: within this distance of the destination
    max_steps: int = 2000  # failure: step limit
    altitude_hidden: int = 50  # NN_altitude: one hidden layer of 50 ReLU
    altitude_epochs: int = 300
    episodes: int = 15_000
    n_envs: int = 64  # episodes run side by side in the batched environment
    hidden: int = 150  # DQN: one hidden layer of 150 ReLU
    # discount of the DQN (the thesis gives none). Expert flights last 200-400 steps: with 0.99 the success
    # bonus is worth 100·0.99³⁰⁰ ≈ 5 at the start, lost in the step rewards; 0.995 keeps it at ≈ 22.
    gamma: float = 0.995
    # discount of the feature expectations μ (Eq 6.6-6.7). Episodes end, so γ = 1 is defined; with γ < 1 the
    # first RBF centres of the route dominate μ(π_E) and the learned w pays the agent to dawdle near them.
    feature_gamma: float = 1.0
    lr: float = 1e-3  # Adam; decays linearly to lr_final during the exploitation phase
    lr_final: float = 1e-5
    epsilon_start: float = 0.9  # ε-greedy, lowered every 100 episodes ...
    epsilon_every_episodes: int = 100
    exploration_fraction: float = 0.75  # ... until 0 after 75 % of the episodes (from episode 11,300 of 15,000: 11,250 rounded up to a block of 100)
    batch_size: int = 5000  # DQN mini-batch
    buffer_size: int = 200_000  # replay memory
    transitions_per_update: int = 50  # one DQN update every 50 environment steps
    target_every_episodes: int = 5  # hard target-network update
    irl_every_episodes: int = 100  # a new w from the QP
    # reward augmentation. 1000, not 100: with γ = 0.995 a bonus of 100 is worth 100·γ⁴⁰⁰ ≈ 13 at the start of
    # a 400-step route, and near the goal it barely outweighed flying past the 5 km disc (docs/applearn.md)
    success_reward: float = 1000.0
    # The penalty must outweigh the discounted sum of step rewards, dominated by the per-step cost w_bias
    # (|w_bias| ≤ ‖w‖ ≤ 1, so ≤ 1/(1-γ) = 200): with -100, leaving the box early was cheaper than flying on,
    # and the DQN learnt to do so (0 % success).
    failure_reward: float = -1000.0
    # The DQN learns Q · reward_scale: a constant factor leaves the optimal policy unchanged, but the Q-net
    # starts near 0 and Adam moves its output ~0.1 per step, so at scale 1 the small budgets are spent growing
    # the output towards the ±1000 of the augmentation. An optimisation choice, so it is not fixed here: each
    # run picks one of `reward_scales` on validation flights carved from its training flights
    # (applearn_eval.select_reward_scale); `reward_scale` is the one a model was trained with.
    reward_scale: float = 0.01
    reward_scales: tuple[float, ...] = (1.0, 0.1, 0.01)
    goal_offset_input: bool = True  # see the module docstring
    # "pick a random initial state from T^E": this share of the episodes starts at a random expert point, the
    # rest at an expert's first point. Mid-route starts reach the goal early in training, so the success
    # bonus is seen at all. μ(π) comes from greedy roll-outs from the first points (policy_feature_expectations).
    start_anywhere_fraction: float = 0.5
    # --- additions beyond the thesis (module docstring); the neutral value switches each off
    route_feature: bool = True  # φ_route in φ (reward and IRL)
    # the DQN's step reward is wᵀφ(s') - Σ_k max(w_k, 0) ≤ 0 (φ_k ∈ [0, 1]): with a step reward that can be
    # positive, flying on near the route forever (r/(1-γ) = 200 r) beat the success bonus (then 100), and the
    # greedy policy flew to the step limit. A constant per step; the IRL step (the QP on μ) is unchanged.
    nonpositive_reward: bool = True
    route_input: bool = True  # the Q-net also sees the signed offset from the route (tanh at 2σ) and the share of it left
    shaping: float = 1.0  # weight of the potential Φ (per step of route left); 0 = no shaping
    # the shaping term is Φ(s') - Φ(s) (a reward for progress along the route) instead of Ng et al.'s
    # γΦ(s') - Φ(s). The potential-based form leaves the optimal policy and hence its action gaps unchanged, and
    # those vanish far from the goal (one more step of progress is worth ≈ (cost + (1-γ)·bonus)·γ^L, L steps to
    # go: 0.24 of a reward unit 400 steps out), so the greedy policy zig-zagged between nearly opposite headings;
    # it also paid (1-γ)|Φ| ≈ 2 per step for standing still far from the goal. Without the γ, progress pays 1 per
    # step wherever it is made. Not policy-invariant: it favours following the route, which is the aim.
    progress_reward: bool = True
    # this share of the training episodes starts at a random point along the experts' route (σ to either side):
    # expert points rarely lie near the goal (mode 0's tracks end anywhere over 200 km), so without them the
    # failing runs never saw a success and never learnt the final approach (from 32 km out they missed the disc)
    route_start_fraction: float = 0.25
    # this share starts on the route's final approach (its last GOAL_START_WIDTHS · σ, σ to either side): only
    # ~1 route start in 16 lies there on mode 0, and the failing mode-0 run's Q-values fell towards the goal
    # (about -8 within 10 km of it, -5 far out): it zig-zagged 5-10 km off the disc (docs/history/applearn.md, fifth investigation)
    goal_start_fraction: float = 0.15
    n_step: int = 10  # n of the n-step return; 1 = the one-step target of the thesis's DQN
    corridor_widths: float = 4.0  # training only: failure beyond this many σ from the route or past the goal; 0 = off
    # return the policy of the IRL step whose greedy roll-outs from the experts' first points (training flights)
    # succeeded most, ties to the latest (Abbeel & Ng also return one of the iterations' policies, not
    # necessarily the last); False = the last one. Greedy success moves between IRL steps (e.g. 1, 1, 0, 1).
    select_policy: bool = True
    # Baird's advantage learning: the TD target loses α (max_a Q⁻(s, a) - Q⁻(s, a_t)), which widens the gaps
    # between the headings' Q-values by ~1/(1-α) (10x at 0.9) without changing the greedy policy of the exact
    # Q. Far from the goal the DQN's gaps were below the Q-net's noise and the greedy policy zig-zagged
    # (docs/history/applearn.md, fourth investigation); 0 = the thesis's DQN target
    advantage_learning: float = 0.9

    def __post_init__(self):
        shares = (self.start_anywhere_fraction, self.route_start_fraction, self.goal_start_fraction)
        if min(shares) < 0 or sum(shares) > 1:  # past 1 the last kinds would silently never be drawn (mix_starts)
            raise ValueError(f"training start shares (anywhere, route, final approach) = {shares}: each >= 0, together <= 1")
        if self.episodes < 1:
            raise ValueError(f"episodes = {self.episodes}: at least 1")
        if not self.reward_scales or min(self.reward_scales) <= 0:
            raise ValueError(f"reward_scales = {self.reward_scales}: at least one, each > 0")


# goal offset (in steps) seen by the DQN through tanh(offset / scale): fine near the goal, coarse far away
GOAL_OFFSET_SCALES_STEPS = (10.0, 100.0)
KM_PER_DEG = 111.2  # km per degree of latitude (and of scaled longitude, lon · cos(lat0))
GOAL_START_WIDTHS = 8.0  # final-approach training starts (goal_start_fraction) lie on the route's last 8 σ (~70-100 km)
ROUTE_POINTS = 100  # vertices of the centroid route polyline

PROFILES = {
    "paper": AppLearnParams(),
    # minutes on 2 cores for all partitions and seeds: fewer, wider batches of episodes, smaller updates, and
    # one reward scale instead of a choice per run (which doubles the training): 0.01, the validated choice
    # over the 40 demo runs of 2026-11-23 (validation success 12.5 % vs 1.3 % for 0.1; docs/history/applearn.md)
    "demo": AppLearnParams(
        reward_scales=(0.01,), altitude_epochs=150, episodes=768, n_envs=256, batch_size=256, buffer_size=100_000,
        transitions_per_update=128, epsilon_every_episodes=64, irl_every_episodes=128, target_every_episodes=16,
    ),
}


# ------------------------------------------------------------------------------------ features φ(s), Eq 6.2-6.3
@dataclass
class RBFFeatures:
    pos_centres: np.ndarray  # (L_pos, 2): lon·cos(lat0), lat of the centroid trajectory at equal time steps
    beta_pos: float
    lon_scale: float  # cos(lat0): makes a degree of longitude as long as a degree of latitude
    meteo_centres: np.ndarray  # (L_meteo, 3) in z-scored weather units
    meteo_mean: np.ndarray  # (3,) mean and std of T [K], u, v [m/s] over the expert points
    meteo_std: np.ndarray
    beta_meteo: float
    route: "Route | None" = None  # φ_route when set

    @property
    def size(self) -> int:
        return len(self.pos_centres) + len(self.meteo_centres) + 1 + (self.route is not None)

    def __call__(self, obs: np.ndarray, route_offset_km: np.ndarray | None = None) -> np.ndarray:
        """φ(s) for observations (N, 7) -> (N, L_pos + L_meteo + 1 [+ 1: φ_route]); a point without weather gets φ_meteo = 0.

        The last feature is a constant 1: its feature expectation is the episode length, so the QP can learn
        a cost per step (experts do not dawdle) instead of paying the agent for every step near the route.
        """
        p = np.stack([obs[:, 0] * self.lon_scale, obs[:, 1]], axis=1)
        v = (obs[:, 4:7] - self.meteo_mean) / self.meteo_std
        phi_pos = np.exp(-self.beta_pos * ((p[:, None, :] - self.pos_centres) ** 2).sum(-1))
        phi_meteo = np.exp(-self.beta_meteo * ((v[:, None, :] - self.meteo_centres) ** 2).sum(-1))
        parts = [phi_pos, phi_meteo, np.ones((len(obs), 1))]
        if self.route is not None:
            offset = self.route.locate(obs)[0] if route_offset_km is None else route_offset_km
            parts.append(np.exp(-0.5 * (offset / self.route.width_km) ** 2)[:, None])
        return np.nan_to_num(np.concatenate(parts, axis=1)).astype(np.float32)


@dataclass
class Route:
    """The experts' centroid route as a polyline in φ_pos's (lon·cos(lat0), lat) frame, ending at the goal."""

    points: np.ndarray  # (ROUTE_POINTS, 2)
    lon_scale: float
    width_km: float  # σ: RMS distance of the expert points to the route, at least one step

    def locate(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(signed offset from the route km, left of the route's line positive; route left to the goal km) per row.

        The closest route point is sought on the two segments at the nearest vertex (one matrix product for
        all rows; exact unless a far segment passes closer than both, which vertices ~15 km apart rule out
        near the route). Every training step calls this for 256 trajectories."""
        p = np.stack([obs[:, 0] * self.lon_scale, obs[:, 1]], axis=1)
        pts, last = self.points, len(self.points) - 2  # last segment index
        vertex = ((p**2).sum(1)[:, None] - 2 * p @ pts.T + (pts**2).sum(1)).argmin(axis=1)
        seg = np.stack([(vertex - 1).clip(0, last), vertex.clip(0, last)], axis=1)  # (N, 2) candidate segments
        a, ab = pts[seg], pts[seg + 1] - pts[seg]
        rel = p[:, None, :] - a
        t = ((rel * ab).sum(-1) / (ab**2).sum(-1).clip(1e-12)).clip(0, 1)
        d2 = ((rel - t[..., None] * ab) ** 2).sum(-1)
        rows = np.arange(len(p))
        j = d2.argmin(axis=1)
        k, ab, rel, t = seg[rows, j], ab[rows, j], rel[rows, j], t[rows, j]
        side = np.sign(ab[:, 0] * rel[:, 1] - ab[:, 1] * rel[:, 0])
        length = np.linalg.norm(np.diff(pts, axis=0), axis=1)
        after = np.concatenate([np.cumsum(length[::-1])[::-1][1:], [0.0]])  # route after each segment's end
        return side * np.sqrt(d2[rows, j]) * KM_PER_DEG, (after[k] + (1 - t) * length[k]) * KM_PER_DEG

    def beyond_goal_km(self, obs: np.ndarray) -> np.ndarray:
        """How far past the goal each point lies along the route's last segment (negative: not yet there)."""
        p = np.stack([obs[:, 0] * self.lon_scale, obs[:, 1]], axis=1)
        last = self.points[-1] - self.points[-2]
        return (p - self.points[-1]) @ (last / np.linalg.norm(last).clip(1e-12)) * KM_PER_DEG

    def sample(self, rng: np.random.Generator, n: int, last_km: float | None = None) -> tuple[np.ndarray, np.ndarray]:
        """n (lon, lat) points spread uniformly along the route (or its last `last_km` before the goal), each moved
        sideways by N(0, σ)."""
        seg = np.diff(self.points, axis=0)
        length = np.linalg.norm(seg, axis=1)
        total = length.sum()
        at = rng.random(n) * total if last_km is None else total - rng.random(n) * min(last_km / KM_PER_DEG, total)
        k = np.searchsorted(np.cumsum(length), at).clip(0, len(seg) - 1)
        t = (at - np.concatenate([[0.0], np.cumsum(length)[:-1]])[k]) / length[k].clip(1e-12)
        normal = np.stack([-seg[k, 1], seg[k, 0]], axis=1) / length[k, None].clip(1e-12)
        p = self.points[k] + t[:, None] * seg[k] + normal * rng.normal(0, self.width_km / KM_PER_DEG, n)[:, None]
        return p[:, 0] / self.lon_scale, p[:, 1]

    @property
    def length_km(self) -> float:
        return float(np.linalg.norm(np.diff(self.points, axis=0), axis=1).sum() * KM_PER_DEG)


def fit_route(tracks: pl.DataFrame, geometry: HeadingGeometry, lon_scale: float) -> Route:
    """The time-normalised centroid of the expert flights, its last vertex moved to the goal; σ from the experts."""
    _, lon_lat = resample_flights(tracks, ROUTE_POINTS)
    points = lon_lat.mean(axis=0)
    points[-1] = geometry.goal_lon, geometry.goal_lat
    route = Route(points * np.array([lon_scale, 1.0]), lon_scale, 1.0)
    offset, _ = route.locate(tracks.select("lon", "lat").to_numpy())
    step_km = np.hypot(geometry.step_lon_deg * lon_scale, geometry.step_lat_deg) * KM_PER_DEG
    route.width_km = float(max(np.sqrt(np.mean(offset**2)), step_km))
    return route


def fit_features(tracks: pl.DataFrame, n_pos: int, n_meteo: int, seed: int) -> RBFFeatures:
    """Centres and widths from the expert flights: β = 1 / (2 d²), d = median spacing of neighbouring centres."""
    from sklearn.cluster import KMeans

    _, lon_lat = resample_flights(tracks, n_pos)
    lon_scale = float(np.cos(np.radians(tracks["lat"].mean())))
    centroid = lon_lat.mean(axis=0) * np.array([lon_scale, 1.0])  # equidistant in time along the centroid
    spacing = np.median(np.linalg.norm(np.diff(centroid, axis=0), axis=1))
    weather = tracks.select(WEATHER_COLUMNS).to_numpy()
    mean, std = weather.mean(axis=0), weather.std(axis=0).clip(1e-6)
    z = (weather - mean) / std
    sample = z[np.random.default_rng(seed).permutation(len(z))[:5000]]
    meteo = KMeans(n_meteo, n_init=2, random_state=seed).fit(sample).cluster_centers_
    gaps = np.linalg.norm(meteo[:, None] - meteo[None], axis=-1) + np.diag(np.full(n_meteo, np.inf))
    return RBFFeatures(
        centroid, float(1 / (2 * max(spacing, 1e-3) ** 2)), lon_scale,
        meteo, mean, std, float(1 / (2 * max(np.median(gaps.min(axis=1)), 1e-3) ** 2)),
    )


def expert_feature_expectations(tracks: pl.DataFrame, features: RBFFeatures, gamma: float) -> np.ndarray:
    """μ(π_E) = 1/M Σ_i Σ_t γᵗ φ(s_t^i) over the M expert flights (Eq 6.6)."""
    tracks = tracks.sort("flight_id", "ts")
    t = tracks.select(pl.int_range(pl.len()).over("flight_id")).to_series().to_numpy()
    discounted = features(expert_observations(tracks)) * gamma ** t[:, None]
    return discounted.sum(axis=0) / tracks["flight_id"].n_unique()


# ---------------------------------------------------------------------------------------- the IRL step (QP)
def max_margin_weights(mu_expert: np.ndarray, mu_policies: np.ndarray) -> tuple[np.ndarray, float]:
    """w with ‖w‖₂ ≤ 1 maximising the margin t by which the expert beats every policy so far (Abbeel & Ng)."""
    import cvxpy as cp

    w, t = cp.Variable(len(mu_expert)), cp.Variable()
    constraints = [cp.norm(w, 2) <= 1, np.atleast_2d(mu_policies) @ w + t <= mu_expert @ w]
    cp.Problem(cp.Maximize(t), constraints).solve(solver=cp.CLARABEL)
    if w.value is None:
        raise RuntimeError("the max-margin QP found no solution")
    return np.asarray(w.value, dtype=np.float64), float(t.value)


# --------------------------------------------------------------------------------------------------- the DQN
class QNetwork(torch.nn.Module):
    def __init__(self, n_inputs: int, n_actions: int, hidden: int):
        super().__init__()
        self.net = torch.nn.Sequential(torch.nn.Linear(n_inputs, hidden), torch.nn.ReLU(), torch.nn.Linear(hidden, n_actions))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x)


@dataclass
class AppLearnModel:
    """A trained AppLearn policy with everything needed to roll it out: geometry, NN_altitude, φ, DQN, w."""

    params: AppLearnParams
    geometry: HeadingGeometry
    altitude: AltitudeNet
    features: RBFFeatures
    q_net: QNetwork | None  # None only while being built
    w: np.ndarray
    # how reward_scale was chosen: validation flight ids and each candidate's score (empty: no choice was made)
    validation: dict = field(default_factory=dict)
    route: Route | None = None  # the experts' centroid route (route_feature, route_input, shaping, corridor)

    def q_input(self, obs: np.ndarray) -> np.ndarray:
        """The DQN's input: φ(s), and (goal_offset_input) the offset to the goal, in steps, squashed at two scales,
        and (route_input) the signed offset from the route (tanh at 2σ) and the share of the route left."""
        return self.encode(obs)[0]

    def encode(self, obs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(DQN input, shaping potential Φ, training failure) of each observation, locating it on the route once.

        Φ(s) = -shaping · (|offset| + route left) / step: minus the distance to the goal along the route, in steps.
        Training failure (corridor_widths): farther than corridor_widths · σ from the route, or past the goal."""
        p, g, n = self.params, self.geometry, len(obs)
        offset, left = self.route.locate(obs) if self.route is not None else (None, None)
        parts = [self.features(obs, offset)]
        if p.goal_offset_input:
            steps = np.stack([(g.goal_lon - obs[:, 0]) / g.step_lon_deg, (g.goal_lat - obs[:, 1]) / g.step_lat_deg], axis=1)
            parts += [np.tanh(steps / scale) for scale in GOAL_OFFSET_SCALES_STEPS]
        if p.route_input:
            parts.append(np.stack([np.tanh(offset / (2 * self.route.width_km)), left / self.route.length_km], axis=1))
        x = np.concatenate(parts, axis=1).astype(np.float32)
        if not (p.shaping or p.corridor_widths):
            return x, np.zeros(n, np.float32), np.zeros(n, bool)
        step_km = np.hypot(g.step_lon_deg * self.route.lon_scale, g.step_lat_deg) * KM_PER_DEG
        potential = (-p.shaping * (np.abs(offset) + left) / step_km).astype(np.float32)
        failed = np.zeros(n, bool)
        if p.corridor_widths:
            # past the goal: the route's end is the nearest route point, and the point lies beyond it
            failed = (np.abs(offset) > p.corridor_widths * self.route.width_km) | (
                (left <= 0) & (self.route.beyond_goal_km(obs) > g.goal_radius_km))
        return x, potential, failed

    @property
    def n_inputs(self) -> int:
        return self.features.size + 2 * len(GOAL_OFFSET_SCALES_STEPS) * self.params.goal_offset_input + 2 * self.params.route_input

    @torch.no_grad()
    def policy(self, obs: np.ndarray) -> np.ndarray:
        """Greedy heading index for each observation."""
        return self.q_net(torch.from_numpy(self.q_input(obs))).argmax(dim=1).numpy()

    def env(self, weather: pl.DataFrame) -> HeadingEnv:
        return HeadingEnv(self.geometry, self.altitude, weather)

    def to_bytes(self) -> bytes:
        buffer = io.BytesIO()
        features = {k: torch.as_tensor(v) for k, v in asdict(replace(self.features, route=None)).items() if k != "route"}
        route = {k: torch.as_tensor(v) for k, v in asdict(self.route).items()} if self.route is not None else None
        torch.save({
            "kind": "applearn", "params": asdict(self.params), "geometry": self.geometry.to_dict(),
            "altitude": self.altitude.state_dict(), "q_net": self.q_net.state_dict(), "w": torch.from_numpy(self.w),
            "features": features, "route": route, "validation": self.validation,
        }, buffer)
        return buffer.getvalue()

    @classmethod
    def load(cls, path: str | Path) -> "AppLearnModel":
        state = _load_state(Path(path), "applearn")
        try:
            params = AppLearnParams(**state["params"])
            unpack = lambda d: {k: v.item() if v.ndim == 0 else v.numpy() for k, v in d.items()}  # noqa: E731
            route = Route(**unpack(state["route"])) if state.get("route") is not None else None
            features = RBFFeatures(**unpack(state["features"]), route=route if params.route_feature else None)
        except (KeyError, TypeError) as e:  # a file of an older or newer AppLearn
            raise ModelFileError(f"{path}: an AppLearn model file of another version ({type(e).__name__}: {e})") from None
        geometry = HeadingGeometry(**state["geometry"])
        altitude = AltitudeNet(params.altitude_hidden)
        altitude.load_state_dict(state["altitude"])
        model = cls(params, geometry, altitude.eval(), features, None, state["w"].numpy(), state.get("validation", {}), route)
        model.q_net = QNetwork(model.n_inputs, len(geometry.headings_rad), params.hidden)
        model.q_net.load_state_dict(state["q_net"])
        model.q_net.eval()
        return model


def _load_state(path: Path, kind: str) -> dict:
    """A saved model's dictionary, or a one-line ModelFileError naming the file."""
    if not path.is_file():
        raise ModelFileError(f"{path}: no such model file")
    try:
        state = torch.load(path, weights_only=True)
    except Exception as e:  # torch raises many kinds for a corrupt or foreign file
        raise ModelFileError(f"{path}: not a readable trafficlearn model file ({type(e).__name__})") from None
    if not isinstance(state, dict) or state.get("kind") != kind:
        found = state.get("kind") if isinstance(state, dict) else type(state).__name__
        raise ModelFileError(f"{path}: expected a {kind} model file, found {found!r}")
    return state


# ---------------------------------------------------------------------------------- training (Algorithm 7)
def mix_starts(rng: np.random.Generator, n: int, params: AppLearnParams, route: Route, altitude, firsts: StartStates,
               anywhere: StartStates) -> tuple[StartStates, np.ndarray]:
    """n training start states and their kind: 0 a random expert's first point, 1 (start_anywhere_fraction) any expert
    point, 2 (route_start_fraction) a point along the experts' route, 3 (goal_start_fraction) one on its final approach
    (a few of those fall inside the goal disc: one-step successes, harmless)."""
    u = rng.random(n)
    lon, lat = route.sample(rng, n)
    ts = firsts.ts_us[rng.integers(0, len(firsts), n)]
    parts = [firsts.take(rng.integers(0, len(firsts), n)), anywhere.take(rng.integers(0, len(anywhere), n)),
             StartStates(lon, lat, altitude.predict(lon, lat), ts)]
    if params.goal_start_fraction:  # drawn only when used: the other starts keep their random stream
        lon, lat = route.sample(rng, n, last_km=GOAL_START_WIDTHS * route.width_km)
        parts.append(StartStates(lon, lat, altitude.predict(lon, lat), ts))
    chosen = StartStates.concat(parts)
    bounds = np.cumsum([params.route_start_fraction, params.start_anywhere_fraction, params.goal_start_fraction])
    kind = np.select([u < bounds[0], u < bounds[1], u < bounds[2]], [2, 1, 3], 0)
    return chosen.take(kind * n + np.arange(n)), kind


def train_applearn(
    tracks: pl.DataFrame, weather: pl.DataFrame, params: AppLearnParams, seed: int,
    log=None,
) -> tuple[AppLearnModel, pl.DataFrame]:
    """Train on the expert flights in `tracks` (tracks_20s rows); returns the model and one row per IRL step."""
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    # Alg 7, line 1: NN_altitude; and the MDP, features and expert feature expectations from the experts
    geometry = fit_geometry(tracks, params.n_headings, params.goal_radius_km, params.max_steps, heading_coverage=params.heading_coverage)
    altitude = fit_altitude_net(tracks, params.altitude_hidden, params.altitude_epochs, seed=seed)
    features = fit_features(tracks, params.n_pos_centres, params.n_meteo_centres, seed)
    route = fit_route(tracks, geometry, features.lon_scale)
    if params.route_feature:
        features.route = route
    mu_expert = expert_feature_expectations(tracks, features, params.feature_gamma)
    w0 = rng.normal(size=features.size)  # Alg 7, line 2: random initial reward weights
    n_actions = len(geometry.headings_rad)
    model = AppLearnModel(params, geometry, altitude, features, None, w0 / np.linalg.norm(w0), route=route)
    model.q_net = q_net = QNetwork(model.n_inputs, n_actions, params.hidden)
    target_net = QNetwork(model.n_inputs, n_actions, params.hidden)
    target_net.load_state_dict(q_net.state_dict())
    optimiser = torch.optim.Adam(q_net.parameters(), lr=params.lr)
    env = model.env(weather)
    firsts, anywhere = StartStates.first_points(tracks), StartStates.all_points(tracks)

    def pick_starts(n: int) -> StartStates:
        return mix_starts(rng, n, params, route, altitude, firsts, anywhere)[0]

    memory = Replay(params.buffer_size, model.n_inputs, params.n_envs)
    obs = env.reset(pick_starts(params.n_envs))
    x, potential, _ = model.encode(obs)
    greedy_env = model.env(weather)  # μ(π) of the current greedy policy is measured in an environment of its own
    finished_success, losses, mu_policies, history = [], [], [], []
    best = None  # (selection key, Q-net parameters, IRL step) of the best IRL step's policy so far
    episodes = updates = 0
    next_target, next_irl = params.target_every_episodes, params.irl_every_episodes
    explore_episodes = params.exploration_fraction * params.episodes
    while episodes < params.episodes:
        # ε-greedy, ε lowered every epsilon_every_episodes episodes from 0.9 to 0
        done_blocks = (episodes // params.epsilon_every_episodes) * params.epsilon_every_episodes
        epsilon = params.epsilon_start * max(0.0, 1.0 - done_blocks / explore_episodes)
        with torch.no_grad():
            greedy = q_net(torch.from_numpy(x)).argmax(dim=1).numpy()
        actions = np.where(rng.random(params.n_envs) < epsilon, rng.integers(0, n_actions, params.n_envs), greedy)
        obs, status = env.step(actions)  # Eq 6.4 + NN_altitude + weather at the new 4D point
        x2, potential2, failed = model.encode(obs)
        status[(status == RUNNING) & failed] = OUT_OF_BOX  # training only: left the corridor or passed the goal
        memory.add(x, x2, actions, status, potential, potential2)

        ended = np.flatnonzero(status != RUNNING)
        if len(ended):
            finished_success.extend(status[ended] == SUCCESS)
            episodes += len(ended)
            obs = env.restart(ended, pick_starts(len(ended)))
            x2[ended], potential2[ended], _ = model.encode(obs[ended])
        x, potential = x2, potential2

        # DQN updates: one per transitions_per_update environment steps
        if episodes > explore_episodes:  # exploitation: the learning rate decays linearly to lr_final
            progress = (episodes - explore_episodes) / max(params.episodes - explore_episodes, 1)
            optimiser.param_groups[0]["lr"] = params.lr + min(progress, 1.0) * (params.lr_final - params.lr)
        while updates < memory.stored // params.transitions_per_update and memory.can_sample(params.n_step):
            losses.append(_dqn_update(model, target_net, optimiser, memory, memory.sample(rng, params.batch_size, params.n_step)))
            updates += 1
        if episodes >= next_target:
            target_net.load_state_dict(q_net.state_dict())
            next_target = (episodes // params.target_every_episodes + 1) * params.target_every_episodes
        if episodes >= next_irl:  # the IRL step: μ of the current policy joins the QP, a new w comes out
            mu_policy, greedy_success = policy_feature_expectations(model, greedy_env, firsts, params.feature_gamma)
            if best is None or greedy_success >= best[0] or not params.select_policy:
                best = (greedy_success, {k: v.clone() for k, v in q_net.state_dict().items()}, len(history))
            mu_policies.append(mu_policy)
            model.w, margin = max_margin_weights(mu_expert, np.stack(mu_policies))
            history.append({
                "episode": episodes, "epsilon": epsilon, "margin": margin, "success_rate": float(np.mean(finished_success)),
                "greedy_success_rate": greedy_success,
                "loss": float(np.mean(losses)) if losses else float("nan"),
                "reward_expert": float(model.w @ mu_expert), "reward_policy": float(model.w @ mu_policies[-1]),
            })
            if log:
                log(f"episode {episodes}/{params.episodes}: ε={epsilon:.2f} success={history[-1]['success_rate']:.2f} "
                    f"(greedy from first points {greedy_success:.2f}) "
                    f"margin={margin:.3f} loss={history[-1]['loss']:.3g}")
            finished_success, losses = [], []
            next_irl = (episodes // params.irl_every_episodes + 1) * params.irl_every_episodes
    if best is not None:
        q_net.load_state_dict(best[1])
    return model, pl.DataFrame(history).with_columns(selected=pl.int_range(pl.len()) == (best[2] if best else -1))


def policy_feature_expectations(model: AppLearnModel, env: HeadingEnv, starts: StartStates, gamma: float) -> tuple[np.ndarray, float]:
    """μ(π) of the greedy policy (Eq 6.7): one roll-out from every start (the experts' first points), and its success rate.

    Alg 7 adds the feature expectations of the policy the RL step found. Estimated from the ε-greedy training
    episodes instead, μ(π) describes mostly random headings: on the demo budget the QP then kept separating the
    expert from those, its margin never moved after the first IRL step, and the fixed w charged every step near
    the route more than one away from it."""
    obs = env.reset(starts)
    mu = model.features(obs).astype(np.float64)
    while (env.status == RUNNING).any():
        running = env.status == RUNNING
        obs, _ = env.step(model.policy(obs))
        mu[running] += gamma ** env.steps[running, None] * model.features(obs[running])
    return mu.mean(axis=0), float((env.status == SUCCESS).mean())


class Replay:
    """Replay memory filled n_envs transitions at a time, so that row i + n_envs is the next transition of row i's
    environment slot (after a finished episode: the next episode's first). That gives n-step windows by indexing.
    Stored: DQN input of s and s', action, status of s', Φ(s), Φ(s'); the reward is recomputed with the current w."""

    def __init__(self, size: int, n_inputs: int, n_envs: int):
        self.size, self.n_envs, self.stored = size, n_envs, 0
        self.x, self.x2 = np.zeros((size, n_inputs), np.float32), np.zeros((size, n_inputs), np.float32)
        self.a, self.status = np.zeros(size, np.int64), np.zeros(size, np.int8)
        self.potential, self.potential2 = np.zeros(size, np.float32), np.zeros(size, np.float32)

    def add(self, x, x2, a, status, potential, potential2) -> None:
        rows = (self.stored + np.arange(self.n_envs)) % self.size
        self.x[rows], self.x2[rows], self.a[rows], self.status[rows] = x, x2, a, status
        self.potential[rows], self.potential2[rows] = potential, potential2
        self.stored += self.n_envs

    def can_sample(self, n_step: int) -> bool:
        return self.stored > (n_step - 1) * self.n_envs

    def sample(self, rng, batch: int, n_step: int) -> np.ndarray:
        """(batch, n_step) rows: n consecutive transitions of one slot, the first drawn from what is stored."""
        first = rng.integers(max(0, self.stored - self.size), self.stored - (n_step - 1) * self.n_envs, batch)
        return (first[:, None] + self.n_envs * np.arange(n_step)) % self.size


def n_step_returns(reward: np.ndarray, status: np.ndarray, gamma: float) -> tuple[np.ndarray, np.ndarray]:
    """Σ_j γʲ r_j over windows (batch, n) of one slot's consecutive transitions, each reward counted only while its
    episode still ran before it; and whether to bootstrap from the window's last s' (no step of it ended the episode)."""
    running = status == RUNNING
    alive = np.concatenate([np.ones((len(reward), 1), bool), np.cumprod(running, axis=1)[:, :-1].astype(bool)], axis=1)
    return (reward * alive * gamma ** np.arange(reward.shape[1])).sum(axis=1), running.all(axis=1)


def _dqn_update(model: AppLearnModel, target_net: QNetwork, optimiser, memory: Replay, rows: np.ndarray) -> float:
    """One Adam step on the n-step TD error of the windows `rows` (batch, n) of the replay memory;
    r_j = c · (wᵀφ(s'_j) + reward augmentation + γΦ(s'_j) - Φ(s_j)); with advantage learning α the target
    also loses α (max_a Q⁻(s, a) - Q⁻(s, a_t))."""
    p = model.params
    status, first = memory.status[rows], rows[:, 0]
    action = torch.from_numpy(memory.a[first])[:, None]
    reward = memory.x2[rows, : model.features.size] @ model.w.astype(np.float32) - p.nonpositive_reward * model.w.clip(min=0).sum()
    reward += np.where(status == SUCCESS, p.success_reward, np.where(status != RUNNING, p.failure_reward, 0.0))
    reward += (1.0 if p.progress_reward else p.gamma) * memory.potential2[rows] - memory.potential[rows]
    returns, bootstrap = n_step_returns(p.reward_scale * reward, status, p.gamma)
    x_first = torch.from_numpy(memory.x[first])
    with torch.no_grad():
        q_next = target_net(torch.from_numpy(memory.x2[rows[:, -1]])).max(dim=1).values
        target = torch.from_numpy(returns.astype(np.float32)) + p.gamma ** rows.shape[1] * torch.from_numpy(bootstrap.astype(np.float32)) * q_next
        if p.advantage_learning:
            q_now = target_net(x_first)
            target -= p.advantage_learning * (q_now.max(dim=1).values - q_now.gather(1, action).squeeze(1))
    q = model.q_net(x_first).gather(1, action).squeeze(1)
    loss = torch.nn.functional.mse_loss(q, target)
    optimiser.zero_grad()
    loss.backward()
    optimiser.step()
    return loss.item()


def demo_or_paper(profile: str, **overrides) -> AppLearnParams:
    """The profile's parameters with explicit overrides (None = keep the profile's value)."""
    if profile not in PROFILES:
        raise ValueError(f"profile {profile!r}: expected one of {', '.join(PROFILES)}")
    return replace(PROFILES[profile], **{k: v for k, v in overrides.items() if v is not None})
