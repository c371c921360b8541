"""Behavioural cloning (MLP): regress the expert's (Δlon, Δlat, Δalt) on the state, MSE, Adam.

Used on its own (the "bc" method: one mode per route, no selector) and as the warm start of both GAILs
(thesis §7.5.3: the policy is pre-trained by BC before adversarial training). The GAILs' selector /
posterior gets the same supervised warm start on the expert's clustered modes (their R_E term alone),
plus the pairs it will judge at prediction time (`candidate_rollouts`).
"""

import torch

from models.trajectory.env import rollout, to_goal_frame
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


def candidate_rollouts(policy: Policy, task: Task, gen: torch.Generator) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """What mode selection shows the selector (§7.4.2): from each training demonstration's first state, one roll-out
    per candidate mode of its route (towards that mode's goal) — labelled with the demonstration's own mode.

    Expert pairs alone never show the selector a roll-out of a wrong mode; where a mode's route is unlike the others'
    (ULLI-UMKK's cruise) it then names the roll-out's own mode whatever the date, and every candidate confirms itself.
    Returns as many (obs, z-scored action, mode) pairs as the task has expert pairs, drawn at random.
    """
    first = (task.start_step == 0).nonzero().squeeze(1)
    routes = [r for r, _ in task.mode_keys]
    same_route = torch.tensor([[a == b for b in routes] for a in routes])  # (M, M), M = the phase's few modes
    k, cand = same_route[task.modes[first]].nonzero(as_tuple=True)
    k = first[k]
    with torch.no_grad():
        ro = rollout(task.env, lambda o: policy.act(o, cand)[0], task.starts[k], task.goals[cand], task.max_steps,
                     torch.zeros(len(k), dtype=torch.float64), task.start_day[k])
    obs, act = ro.obs[ro.live], ro.actions[ro.live]
    label = task.modes[k].expand(ro.live.shape)[ro.live]
    pick = torch.randint(len(obs), (len(task.obs),), generator=gen)
    return obs[pick], policy.act_scaler(to_goal_frame(obs[pick], act[pick])), label[pick]


def train_mode_classifier(selector: Selector, policy: Policy, task: Task, epochs: int, gen: torch.Generator) -> list[float]:
    """min_ψ E_(s,a,c)~expert ∪ candidate roll-outs CE(C_ψ(·|s,a), c); returns the mean loss per epoch."""
    r_obs, r_act, r_mode = candidate_rollouts(policy, task, gen)
    obs, act_z, modes = torch.cat([task.obs, r_obs]), torch.cat([policy.act_scaler(task.actions), r_act]), torch.cat([task.modes, r_mode])
    ce = torch.nn.functional.cross_entropy
    return _fit(selector.parameters(), lambda b: ce(selector(obs[b], act_z[b]), modes[b], label_smoothing=LABEL_SMOOTHING),
                len(obs), epochs, gen)
