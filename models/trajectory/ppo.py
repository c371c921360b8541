"""What both GAILs share: generator roll-outs from expert start states, the discriminator loss with its
switch (WGAN-GP critic | BCE + gradient penalty), and the PPO generator update with GAE.
"""

from dataclasses import dataclass

import torch

from models.trajectory.env import rollout
from models.trajectory.nets import Critic, Discriminator, Policy
from models.trajectory.task import Task

# --- hyperparameters (PPO, Schulman et al. 2017) ---------------------------------------------
GAMMA = 0.99
GAE_LAMBDA = 0.95
CLIP = 0.2
PPO_EPOCHS = 4
MINIBATCH = 1024
POLICY_LR = 1e-4  # small: the policy starts from BC and must not forget it in a few iterations
CRITIC_LR = 1e-3
DISC_LR = 3e-4
LAMBDA_GP = 1.0  # λ_GP of Eq 7.5 / 7.6

DISCRIMINATORS = ("wgan_gp", "bce_gp")


@dataclass
class Generated:
    """Live generator steps, flattened: what the discriminator, the selector and PPO consume."""

    obs: torch.Tensor
    act_z: torch.Tensor
    modes: torch.Tensor
    logp: torch.Tensor
    live: torch.Tensor  # (T, B) for GAE
    next_obs: torch.Tensor  # (T, B, OBS_DIM)
    mode_tb: torch.Tensor  # (T, B)
    reached: torch.Tensor  # (B,)
    obs_tb: torch.Tensor  # (T, B, OBS_DIM)


def generate(task: Task, policy: Policy, n_traj: int, horizon: int, gen: torch.Generator) -> Generated:
    """Roll out n_traj stochastic trajectories from expert states (fair across modes) with their true modes."""
    idx = task.fair_sample(n_traj, gen)
    mode = task.modes[idx]
    with torch.no_grad():
        z_steps: list[torch.Tensor] = []

        def act(obs):
            d = policy.dist(obs, mode)
            z = d.mean + d.stddev * torch.randn(d.mean.shape, generator=gen)
            z_steps.append(z)
            return policy.to_env(obs, z)

        ro = rollout(task.env, act, task.starts[idx], task.pair_goal[idx], horizon, task.start_step[idx] * task.env.cfg.dt_s, task.start_day[idx])
        z_tb = torch.stack(z_steps)
        T, B = ro.live.shape
        mode_tb = mode.expand(T, B)
        logp_tb = policy.dist(ro.obs.reshape(T * B, -1), mode_tb.reshape(-1)).log_prob(z_tb.reshape(T * B, 3)).sum(-1).view(T, B)
    live = ro.live
    next_obs = torch.cat([ro.obs[1:], ro.last_obs[None]])
    return Generated(ro.obs[live], z_tb[live], mode_tb[live], logp_tb[live], live, next_obs, mode_tb, ro.reached, ro.obs)


def gradient_penalty(disc: Discriminator, x_expert: torch.Tensor, x_fake: torch.Tensor, gen: torch.Generator) -> torch.Tensor:
    """λ_GP E_x̂[(‖∇_x̂ D(x̂)‖₂ − 1)²] on random interpolates between expert and generated inputs (WGAN-GP)."""
    eps = torch.rand(len(x_expert), 1, generator=gen)
    x_hat = (eps * x_expert + (1 - eps) * x_fake).requires_grad_(True)
    grad = torch.autograd.grad(disc(x_hat).sum(), x_hat, create_graph=True)[0]
    return LAMBDA_GP * ((grad.norm(dim=1) - 1) ** 2).mean()


def disc_loss(kind: str, logit_expert: torch.Tensor, logit_fake: torch.Tensor, fake_weight: torch.Tensor | None = None) -> torch.Tensor:
    """Discriminator loss; logits are 'expert-ness'. D(·) = P(generated) = 1 − σ(logit) in Eq 7.5/7.6.

    bce_gp:  −E_E[log(1 − D)] − E_G[w log D]  (the thesis's minimax with the authors' sigmoid output)
    wgan_gp: E_G[w f] − E_E[f]                 (Wasserstein critic f = logit)
    """
    w = torch.ones_like(logit_fake) if fake_weight is None else fake_weight
    if kind == "bce_gp":
        bce = torch.nn.functional.binary_cross_entropy_with_logits
        return bce(logit_expert, torch.ones_like(logit_expert)) + (w * bce(logit_fake, torch.zeros_like(logit_fake), reduction="none")).mean()
    if kind == "wgan_gp":
        return (w * logit_fake).mean() - logit_expert.mean()
    raise ValueError(f"discriminator must be one of {DISCRIMINATORS}, got '{kind}'")


def fool_loss(kind: str, logit: torch.Tensor) -> torch.Tensor:
    """Loss of a player whose samples should look expert to D: −log(1 − D) for bce_gp, −f for wgan_gp."""
    if kind == "bce_gp":
        return torch.nn.functional.binary_cross_entropy_with_logits(logit, torch.ones_like(logit))
    return -logit.mean()


def disc_reward(kind: str, logit: torch.Tensor) -> torch.Tensor:
    """Surrogate reward r = −log D(·) = softplus(logit) for bce_gp; the critic value for wgan_gp; standardised."""
    r = torch.nn.functional.softplus(logit) if kind == "bce_gp" else logit
    return (r - r.mean()) / (r.std() + 1e-8)


def ppo_update(policy: Policy, critic: Critic, opts: tuple[torch.optim.Optimizer, torch.optim.Optimizer],
               batch: Generated, reward: torch.Tensor, entropy_coef: float, gen: torch.Generator) -> float:
    """One PPO update on a generator batch; reward is per live step (flattened like batch.obs). Returns the policy loss."""
    T, B = batch.live.shape
    with torch.no_grad():
        flat = lambda x: x.reshape(T * B, -1)  # noqa: E731
        v = critic(flat(batch.obs_tb), batch.mode_tb.reshape(-1)).view(T, B)
        v_next = critic(flat(batch.next_obs), batch.mode_tb.reshape(-1)).view(T, B)
        r = torch.zeros(T, B)
        r[batch.live] = reward
        last = batch.live & ~torch.cat([batch.live[1:], torch.zeros(1, B, dtype=torch.bool)])
        terminal = last & batch.reached[None]  # reaching the goal ends the episode; other ends are truncations
        delta = r + GAMMA * v_next * (~terminal) - v
        adv = torch.zeros(T, B)
        running = torch.zeros(B)
        for t in reversed(range(T)):  # GAE: A_t = δ_t + γλ A_{t+1}, reset at each trajectory's end
            running = delta[t] + GAMMA * GAE_LAMBDA * running * (~last[t])
            adv[t] = running
        ret = (adv + v)[batch.live]
        adv = adv[batch.live]
        adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    popt, copt = opts
    n = len(batch.obs)
    for _ in range(PPO_EPOCHS):
        for mb in torch.randperm(n, generator=gen).split(MINIBATCH):
            d = policy.dist(batch.obs[mb], batch.modes[mb])
            ratio = (d.log_prob(batch.act_z[mb]).sum(-1) - batch.logp[mb]).exp()
            # L^CLIP = E[min(ρ A, clip(ρ, 1±ε) A)] + λ_H H(π)
            p_loss = -torch.min(ratio * adv[mb], ratio.clamp(1 - CLIP, 1 + CLIP) * adv[mb]).mean() - entropy_coef * d.entropy().sum(-1).mean()
            popt.zero_grad()
            p_loss.backward()
            popt.step()
            c_loss = ((critic(batch.obs[mb], batch.modes[mb]) - ret[mb]) ** 2).mean()
            copt.zero_grad()
            c_loss.backward()
            copt.step()
    return float(p_loss.item())


def expert_batch(task: Task, policy: Policy, n: int, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """n expert (obs, z-scored action, mode), fair across modes."""
    idx = task.fair_sample(n, gen)
    return task.obs[idx], policy.act_scaler(task.actions[idx]), task.modes[idx]
