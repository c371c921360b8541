"""Triple-GAIL-GP (thesis Eq 7.5, Alg 8): conditional policy π(a|s,c), discriminator D(s,a,c), selector C(c|s,a).

  min_{θ,ψ} max_w  E_E[log(1 − D(s,a,c))] + ω E_π[log D(s,a,c)] + (1−ω) E_C[log D(s,a,ĉ)]
                   + λ_E R_E + λ_G R_G − λ_H H(π) + λ_GP E_x̂[(‖∇D(x̂)‖ − 1)²]
  R_E = CE(C(·|s_E,a_E), c_E)   (selector learns the expert's modes)
  R_G = CE(C(·|s_G,a_G), c_G)   (selector agrees with the generator's modes)
  generator reward r = −log D(s,a,c), PPO.
The selector's samples are generated pairs labelled with the selector's own soft mode ĉ (Alg 8).
"""

import torch

from models.trajectory.nets import Critic, Discriminator, Policy, Selector
from models.trajectory.ppo import CRITIC_LR, DISC_LR, POLICY_LR, disc_loss, disc_reward, fool_loss, expert_batch, generate, gradient_penalty, ppo_update
from models.trajectory.task import Task

# --- hyperparameters -------------------------------------------------------------------------
OMEGA = 0.5  # ω: weight of generator vs selector samples in D's "fake" term
LAMBDA_E = 0.5
LAMBDA_G = 0.5
LAMBDA_H = 0.01  # entropy bonus of the policy
N_TRAJECTORIES = 256  # roll-outs per iteration, started at expert states fair across modes
HORIZON = 45  # steps per roll-out (15 min at 20 s)
DISC_STEPS = 2  # discriminator/selector updates per iteration


def train(policy: Policy, selector: Selector, task: Task, iterations: int, discriminator: str, gen: torch.Generator) -> dict:
    critic = Critic(task.n_modes, policy.obs_scaler)
    disc = Discriminator(policy.obs_scaler, n_modes=task.n_modes)
    opts = (torch.optim.Adam(policy.parameters(), lr=POLICY_LR), torch.optim.Adam(critic.parameters(), lr=CRITIC_LR))
    d_opt = torch.optim.Adam(disc.parameters(), lr=DISC_LR, betas=(0.5, 0.9))
    c_opt = torch.optim.Adam(selector.parameters(), lr=DISC_LR)
    onehot = lambda c: torch.nn.functional.one_hot(c, task.n_modes).float()  # noqa: E731
    history = {"disc_loss": [], "selector_loss": [], "policy_loss": [], "reached": []}
    for _ in range(iterations):
        g = generate(task, policy, N_TRAJECTORIES, HORIZON, gen)
        e_obs, e_act, e_mode = expert_batch(task, policy, len(g.obs), gen)
        for _ in range(DISC_STEPS):
            c_hat = selector(g.obs, g.act_z).softmax(-1)  # ĉ for the selector's samples
            x_e, x_g = disc.inputs(e_obs, e_act, onehot(e_mode)), disc.inputs(g.obs, g.act_z, onehot(g.modes))
            x_c = disc.inputs(g.obs, g.act_z, c_hat.detach())
            w = torch.cat([torch.full((len(x_g),), 2 * OMEGA), torch.full((len(x_c),), 2 * (1 - OMEGA))])
            d_loss = disc_loss(discriminator, disc(x_e), disc(torch.cat([x_g, x_c])), w) + gradient_penalty(disc, x_e, x_g, gen)
            d_opt.zero_grad()
            d_loss.backward()
            d_opt.step()
            # Selector: R_E + R_G, plus its adversarial term (its labelled pairs should look expert to D).
            ce = torch.nn.functional.cross_entropy
            logit_c = disc(disc.inputs(g.obs, g.act_z, selector(g.obs, g.act_z).softmax(-1)))
            c_loss = (LAMBDA_E * ce(selector(e_obs, e_act), e_mode) + LAMBDA_G * ce(selector(g.obs, g.act_z), g.modes)
                      + (1 - OMEGA) * fool_loss(discriminator, logit_c))
            c_opt.zero_grad()
            c_loss.backward()
            c_opt.step()
        with torch.no_grad():
            reward = disc_reward(discriminator, disc(disc.inputs(g.obs, g.act_z, onehot(g.modes))))  # r = −log D(s,a,c)
        history["policy_loss"].append(ppo_update(policy, critic, opts, g, reward, LAMBDA_H, gen))
        history["disc_loss"].append(float(d_loss.item()))
        history["selector_loss"].append(float(c_loss.item()))
        history["reached"].append(float(g.reached.float().mean()))
    return history
