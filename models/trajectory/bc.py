"""Behavioural cloning (MLP): regress the expert's (Δlon, Δlat, Δalt) on the state, MSE, Adam.

Used on its own (the "bc" method: one mode per route, no selector) and as the warm start of both GAILs
(thesis §7.5.3: the policy is pre-trained by BC before adversarial training). The GAILs' selector /
posterior gets the same supervised warm start on the expert's clustered modes (their R_E term alone).
"""

import torch

from models.trajectory.nets import Policy, Selector
from models.trajectory.task import Task

# --- hyperparameters -------------------------------------------------------------------------
LEARNING_RATE = 3e-3
BATCH_SIZE = 1024
LABEL_SMOOTHING = 0.1  # keeps the selector's probabilities calibrated: mode selection compares their means


def _fit(params, loss_of_batch, n: int, epochs: int, gen: torch.Generator) -> list[float]:
    """Adam over shuffled minibatches of n samples; returns the mean loss per epoch."""
    opt = torch.optim.Adam(params, lr=LEARNING_RATE)
    losses = []
    for _ in range(epochs):
        perm = torch.randperm(n, generator=gen)
        total = 0.0
        for b in perm.split(BATCH_SIZE):
            loss = loss_of_batch(b)
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += loss.item() * len(b)
        losses.append(total / n)
    return losses


def train_bc(policy: Policy, task: Task, epochs: int, gen: torch.Generator) -> list[float]:
    """min_θ E_(s,a,c)~expert ‖μ_θ(s, c) − a‖² in z-scored action units; returns the mean loss per epoch."""
    target = policy.act_scaler(task.actions)
    modes = task.modes if policy.n_modes == task.n_modes else torch.zeros_like(task.modes)
    return _fit(policy.parameters(), lambda b: ((policy.mean_z(task.obs[b], modes[b]) - target[b]) ** 2).mean(), len(task.obs), epochs, gen)


def train_mode_classifier(selector: Selector, policy: Policy, task: Task, epochs: int, gen: torch.Generator) -> list[float]:
    """min_ψ E_(s,a,c)~expert CE(C_ψ(·|s,a), c); returns the mean loss per epoch."""
    act_z = policy.act_scaler(task.actions)
    ce = torch.nn.functional.cross_entropy
    return _fit(selector.parameters(), lambda b: ce(selector(task.obs[b], act_z[b]), task.modes[b], label_smoothing=LABEL_SMOOTHING),
                len(task.obs), epochs, gen)
