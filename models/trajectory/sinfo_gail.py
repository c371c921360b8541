"""sInfo-GAIL-GP (thesis Eq 7.6-7.7, Alg 9): supervised InfoGAIL with discriminator D(s,a) and posterior Q(c|s,a).

  min_{θ,ψ} max_w  E_E[log(1 − D(s,a))] + E_π[log D(s,a)] − λ_H H(π) − λ_I L_I(π, Q) + λ_GP E_x̂[(‖∇D(x̂)‖ − 1)²]
  L_I = E_{c, (s,a)~π(·|c)}[log Q(c|s,a)]   (variational lower bound of the mutual information)
  supervised: Q also learns the expert's clustered modes (CE on expert pairs).
  generator reward (Eq 7.7): r = −log D(s,a)·l_D + log Q(c|s,a)·l_Q, PPO.
"""

import torch

from models.trajectory.nets import Critic, Discriminator, Policy, Selector
from models.trajectory.ppo import CRITIC_LR, DISC_LR, POLICY_LR, disc_loss, disc_reward, expert_batch, generate, gradient_penalty, ppo_update
from models.trajectory.task import Task

# --- hyperparameters -------------------------------------------------------------------------
LAMBDA_H = 0.01
LAMBDA_I = 0.5
L_D = 1.0  # l_D of Eq 7.7
L_Q = LAMBDA_I  # l_Q of Eq 7.7
N_TRAJECTORIES = 256
HORIZON = 45
DISC_STEPS = 2


def train(policy: Policy, posterior: Selector, task: Task, iterations: int, discriminator: str, gen: torch.Generator) -> dict:
    critic = Critic(task.n_modes, policy.obs_scaler)
    disc = Discriminator(policy.obs_scaler)
    opts = (torch.optim.Adam(policy.parameters(), lr=POLICY_LR), torch.optim.Adam(critic.parameters(), lr=CRITIC_LR))
    d_opt = torch.optim.Adam(disc.parameters(), lr=DISC_LR, betas=(0.5, 0.9))
    q_opt = torch.optim.Adam(posterior.parameters(), lr=DISC_LR)
    ce = torch.nn.functional.cross_entropy
    history = {"disc_loss": [], "posterior_loss": [], "policy_loss": [], "reached": []}
    for _ in range(iterations):
        g = generate(task, policy, N_TRAJECTORIES, HORIZON, gen)
        e_obs, e_act, e_mode = expert_batch(task, policy, len(g.obs), gen)
        for _ in range(DISC_STEPS):
            x_e, x_g = disc.inputs(e_obs, e_act), disc.inputs(g.obs, g.act_z)
            d_loss = disc_loss(discriminator, disc(x_e), disc(x_g)) + gradient_penalty(disc, x_e, x_g, gen)
            d_opt.zero_grad()
            d_loss.backward()
            d_opt.step()
            # Posterior: maximise L_I on generated pairs and fit the expert's labelled modes.
            q_loss = ce(posterior(g.obs, g.act_z), g.modes) + ce(posterior(e_obs, e_act), e_mode)
            q_opt.zero_grad()
            q_loss.backward()
            q_opt.step()
        with torch.no_grad():
            log_q = posterior(g.obs, g.act_z).log_softmax(-1).gather(1, g.modes[:, None]).squeeze(1)
            reward = L_D * disc_reward(discriminator, disc(disc.inputs(g.obs, g.act_z))) + L_Q * log_q  # Eq 7.7
        history["policy_loss"].append(ppo_update(policy, critic, opts, g, reward, LAMBDA_H, gen))
        history["disc_loss"].append(float(d_loss.item()))
        history["posterior_loss"].append(float(q_loss.item()))
        history["reached"].append(float(g.reached.float().mean()))
    return history
