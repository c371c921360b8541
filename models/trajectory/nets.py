"""Networks of the multi-modal GAIL learners (SPEC §2 / thesis §7.5.3), each carrying its own input scaling.

Policy:        state -> 2 FC; mode one-hot -> 1 FC; concat -> 1 FC -> mean of the action (z-scored, goal frame:
               along/cross the direction to the goal and Δalt; `act` returns (Δlon, Δlat, Δalt));
               a state-independent log-std makes it a Gaussian policy.
Critic:        state (+ mode) -> 100-100-32 -> V.
Discriminator: (state, action[, mode]) -> 100-100 tanh -> 1 logit (higher = more expert-like).
Selector:      (state, action) -> 100-100 -> M mode logits (Triple-GAIL's selector C, sInfo-GAIL's posterior Q).
The z-scoring statistics are buffers, so a saved state dict is the whole model.
"""

import torch
from torch import nn

from models.trajectory.env import OBS_DIM, OBS_NAMES, from_goal_frame


class Scaler(nn.Module):
    def __init__(self, mean: torch.Tensor, std: torch.Tensor):
        super().__init__()
        self.register_buffer("mean", torch.as_tensor(mean, dtype=torch.float32))
        self.register_buffer("std", torch.as_tensor(std, dtype=torch.float32).clamp_min(1e-6))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return (x.to(torch.float32) - self.mean) / self.std

    def inverse(self, z: torch.Tensor) -> torch.Tensor:
        return z * self.std + self.mean


def mlp(sizes: list[int], act=nn.Tanh) -> nn.Sequential:
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(act())
    return nn.Sequential(*layers)


class Policy(nn.Module):
    def __init__(self, n_modes: int, obs_scaler: Scaler, act_scaler: Scaler, hidden: int = 100, mode_hidden: int = 32):
        super().__init__()
        self.n_modes = n_modes
        self.obs_scaler, self.act_scaler = obs_scaler, act_scaler
        self.state_net = nn.Sequential(mlp([OBS_DIM, hidden, hidden]), nn.Tanh())
        self.mode_net = nn.Sequential(nn.Linear(n_modes, mode_hidden), nn.Tanh())
        self.head = mlp([hidden + mode_hidden, hidden, 3])
        self.log_std = nn.Parameter(torch.full((3,), -1.0))

    def mean_z(self, obs: torch.Tensor, mode: torch.Tensor) -> torch.Tensor:
        """Mean action in z-scored units; mode = (B,) global mode index."""
        onehot = nn.functional.one_hot(mode, self.n_modes).to(torch.float32)
        return self.head(torch.cat([self.state_net(self.obs_scaler(obs)), self.mode_net(onehot)], dim=1))

    def dist(self, obs: torch.Tensor, mode: torch.Tensor) -> torch.distributions.Normal:
        return torch.distributions.Normal(self.mean_z(obs, mode), self.log_std.exp())

    def act(self, obs: torch.Tensor, mode: torch.Tensor, deterministic: bool = True) -> tuple[torch.Tensor, torch.Tensor]:
        """(physical action (Δlon, Δlat, Δalt) in the positions' dtype, z-scored goal-frame action)."""
        d = self.dist(obs, mode)
        z = d.mean if deterministic else d.sample()
        return self.to_env(obs, z), z

    def to_env(self, obs: torch.Tensor, z: torch.Tensor) -> torch.Tensor:
        return from_goal_frame(obs, self.act_scaler.inverse(z).to(obs.dtype))


class Critic(nn.Module):
    def __init__(self, n_modes: int, obs_scaler: Scaler):
        super().__init__()
        self.n_modes, self.obs_scaler = n_modes, obs_scaler
        self.net = mlp([OBS_DIM + n_modes, 100, 100, 32, 1])

    def forward(self, obs: torch.Tensor, mode: torch.Tensor) -> torch.Tensor:
        onehot = nn.functional.one_hot(mode, self.n_modes).to(torch.float32)
        return self.net(torch.cat([self.obs_scaler(obs), onehot], dim=1)).squeeze(-1)


class Discriminator(nn.Module):
    """D(s, a) or, with n_modes > 0, D(s, a, c). Inputs: raw obs, z-scored action."""

    def __init__(self, obs_scaler: Scaler, n_modes: int = 0):
        super().__init__()
        self.n_modes, self.obs_scaler = n_modes, obs_scaler
        self.net = mlp([OBS_DIM + 3 + n_modes, 100, 100, 1])

    def inputs(self, obs: torch.Tensor, act_z: torch.Tensor, mode_probs: torch.Tensor | None = None) -> torch.Tensor:
        parts = [self.obs_scaler(obs), act_z.to(torch.float32)]
        if self.n_modes:
            parts.append(mode_probs.to(torch.float32))
        return torch.cat(parts, dim=1)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.net(x).squeeze(-1)


# The selector must not see the goal: at prediction every candidate mode's roll-out heads for that mode's
# goal, so a goal-aware selector would just read the mode back from it instead of judging the behaviour.
SELECTOR_FEATURES = [i for i, n in enumerate(OBS_NAMES) if not n.startswith("goal_")]


class Selector(nn.Module):
    """C(c | s, a) / Q(c | s, a): mode logits from a state-action pair (state without the goal features)."""

    def __init__(self, n_modes: int, obs_scaler: Scaler):
        super().__init__()
        self.obs_scaler = obs_scaler
        self.net = nn.Sequential(mlp([len(SELECTOR_FEATURES) + 3, 100, 100]), nn.Tanh(), nn.Linear(100, n_modes))

    def forward(self, obs: torch.Tensor, act_z: torch.Tensor) -> torch.Tensor:
        return self.net(torch.cat([self.obs_scaler(obs)[:, SELECTOR_FEATURES], act_z.to(torch.float32)], dim=1))
