"""col-MARL and its i-MARL ablation: one DDQN per route agent (route x vehicle class), Algorithm 6.

Single file, CleanRL style: hyperparameters first, then the Q-networks, the rollout of one episode
(run in worker processes, one libsumo each) and the training loop. Every vehicle of a route agent is
an independent copy of it; the experience of all of them fills that agent's replay buffer.

All route agents have the same architecture (state -> 128 tanh -> 5 accelerations), so their weights
are stacked on a leading agent axis: agent k only ever sees its own parameters and its own loss (Adam
is element-wise, so one optimiser over the stack equals one optimiser per agent), and a batch of all
agents trains in one `bmm`.

Variant "col" is col-MARL (state Eq 4.2, reward Eq 4.3-4.7); "ind" is i-MARL (no collision and density
terms, reward Eq 3.2-3.3). The environment is models.urban.env.UrbanParallelEnv. Variant "ch3" (chapter 3:
speed actions, DQN + CNN over a collision matrix) plugs its own env and network into the same loop
(models.urban.cnn_marl, see `kit`).
"""

import functools
import itertools
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import torch
from torch import nn

from models.urban import kernels
from models.urban.checkpoint import Checkpoint, fingerprint
from models.urban.env import GOAL_REWARD, STATE_DIM, UrbanParallelEnv, route_agent
from models.urban.sim import ScenarioFiles

# --- hyperparameters (§4.3.1) ------------------------------------------------------------------
HIDDEN = 128  # one tanh hidden layer
N_ACTIONS = 5  # Table 4.1: Decel_L, Decel_M, 0, Accel_M, Accel_L
LEARNING_RATE = 1e-3  # Adam
GAMMA = 0.99
BATCH_SIZE = 2500  # per route agent and gradient step
BUFFER_SIZE = 25_000  # per route agent
TARGET_EVERY_EPISODES = 5  # hard update of the target networks
EPSILON_START = 0.9  # decays linearly to 0 ...
EXPLORATION_FRACTION = 0.8  # ... over this share of the episodes; the rest is pure exploitation
# the thesis trains "at the end of each episode" without saying how much: 40 steps beat 10 at the demo's 50 episodes
# (fewer collisions on Sc1 and the real network, docs/history/urban.md) for 2-4x the training time; chapter 3's variant keeps its own (cnn_marl)
GRADIENT_STEPS_PER_EPISODE = 40
# Q is learnt on rewards / L (same greedy policy): with rewards of ±L = ±1000 the tanh net's output would need at least
# ~7,800 Adam steps at lr 1e-3 just to reach the scale of Q (a step moves it by at most lr x 129 output-layer weights),
# more than the demo's whole budget (50 episodes x 40 gradient steps)
REWARD_SCALE = 1.0 / GOAL_REWARD
# training log: a row per route agent for every k-th episode and the last, k = max(episodes // LOG_EPISODES, 1); the
# paper profile's every episode would be ~740 M rows (~90 GB), its logged ones ~10 M (the demo logs every episode)
LOG_EPISODES = 200
PROGRESS_EVERY_S = 300.0  # a progress line (episode, rate, time left) at every 10 % of the episodes and at least this often
CHUNK_ROWS = 20_000  # batch rows (agents x transitions) per forward/backward pass of a gradient step: speed only


class RouteAgentsQ(nn.Module):
    """Q(s, ·) of every route agent: weights stacked as [agent, ...]."""

    def __init__(self, n_agents: int, state_dim: int, generator: torch.Generator):
        super().__init__()

        def init(*shape, fan_in):  # PyTorch's default Linear initialisation, per agent
            bound = 1.0 / np.sqrt(fan_in)
            return nn.Parameter((torch.rand(*shape, generator=generator) * 2 - 1) * bound)

        self.w1, self.b1 = init(n_agents, state_dim, HIDDEN, fan_in=state_dim), init(n_agents, HIDDEN, fan_in=state_dim)
        self.w2, self.b2 = init(n_agents, HIDDEN, N_ACTIONS, fan_in=HIDDEN), init(n_agents, N_ACTIONS, fan_in=HIDDEN)

    def forward(self, x: torch.Tensor, agents: slice = slice(None)) -> torch.Tensor:
        """x [agent, batch, state] -> Q [agent, batch, action] of the route agents `agents` = tanh(x w1 + b1) w2 + b2,
        computed as σ(x 2w1 + 2b1) 2w2 + (b2 - Σ_h w2): tanh(z) = 2σ(2z) - 1 folded into the small weight tensors,
        because torch's CPU tanh costs 3x its sigmoid and was 40 % of a gradient step (same function and gradients)."""
        w1, b1, w2, b2 = self.w1[agents], self.b1[agents], self.w2[agents], self.b2[agents]
        s = torch.sigmoid(torch.baddbmm(2 * b1[:, None], x, 2 * w1))
        return torch.baddbmm((b2 - w2.sum(dim=1))[:, None], s, 2 * w2)


def q_values(params: dict[str, np.ndarray], states: np.ndarray, agent_idx: np.ndarray) -> np.ndarray:
    """Q of each vehicle under its own route agent, without torch (rollout workers need none): compiled dense layers
    (numpy's per-agent weight gathers and einsums were ~40 µs per decision with a handful of vehicles), numpy's tanh."""
    h = np.tanh(kernels.dense(states, params["w1"], params["b1"], agent_idx))
    return kernels.dense(h, params["w2"], params["b2"], agent_idx)


@dataclass(frozen=True)
class Kit:
    """What a learner variant plugs into the shared rollout and training loop."""

    network: type  # Q-network class: (n_agents, state_dim, generator), forward [agent, batch, state] -> [agent, batch, action]
    q_values: Callable  # numpy Q for the rollout workers: (params, states, agent_idx) -> [n, action]
    state_dim: int
    env: type  # PettingZoo parallel env: (files, variant, sumo_seed=, record=, leader_guard=)
    buffer_size: int
    gradient_steps: int  # per episode
    n_actions: int


def kit(variant: str) -> Kit:
    """col-MARL ("col"), i-MARL ("ind") or chapter 3's DQN + CNN ("ch3", models.urban.cnn_marl)."""
    if variant == "ch3":
        from models.urban import cnn_marl  # imports this module: loaded on demand

        return Kit(cnn_marl.RouteAgentsDQNCNN, cnn_marl.q_values, cnn_marl.STATE_DIM, cnn_marl.Ch3Env, cnn_marl.BUFFER_SIZE,
                   cnn_marl.GRADIENT_STEPS_PER_EPISODE, len(cnn_marl.SPEEDS_MPS))
    if variant not in STATE_DIM:
        raise ValueError(f"variant {variant!r}: expected one of {sorted([*STATE_DIM, 'ch3'])}")
    return Kit(RouteAgentsQ, q_values, STATE_DIM[variant], UrbanParallelEnv, BUFFER_SIZE, GRADIENT_STEPS_PER_EPISODE, N_ACTIONS)


# --- one episode (runs in a worker process) -------------------------------------------------------


@dataclass
class EpisodeJob:
    files: ScenarioFiles
    variant: str
    agents: list  # route agent names, index = position in the weight stack
    params: dict  # numpy weights of RouteAgentsQ
    epsilon: float
    seed: int  # exploration and SUMO seed of this episode
    n_vehicles: int
    record: bool = False
    leader_guard: bool = True  # SUMO's car-following safety on (see models.urban.env)
    shield: bool = False  # the env's optional safety layer: actions outside infos[v]["action_mask"] are never chosen (col/ind only)


@dataclass
class EpisodeResult:
    transitions: dict  # agent_idx, state, action, reward, next_state, done (+ allowed, next_allowed under the layer): arrays
    agent_return: np.ndarray  # mean return of the vehicles of each route agent (nan: none drove)
    metrics: dict
    frames: list = field(default_factory=list)  # 1 s snapshots if recorded
    collided: set = field(default_factory=set)
    teleported: set = field(default_factory=set)
    vehicle_substeps: int = 0  # vehicles x simulation steps, for throughput figures


PER_VEHICLE = ("reward", "next_state", "done")  # rollout buffers kept as one item per vehicle and decision, the others per decision


def _as_array(key: str, items: list) -> np.ndarray:
    """A rollout buffer as one array: the per-decision arrays concatenated, the per-vehicle items (PER_VEHICLE) made into
    one array at the end (cheaper than an array per decision)."""
    if not items:
        return np.zeros(0)
    if key in PER_VEHICLE:
        return np.array(items, np.float32 if key == "next_state" else float)
    return np.concatenate(items)


def run_episode(job: EpisodeJob) -> EpisodeResult:
    """Roll out one episode with ε-greedy route agents; returns every vehicle's transitions."""
    rng = np.random.default_rng(job.seed)
    bitgen = kernels.bit_generator(rng)  # the exploration draws rng.random / rng.integers, made in one kernel call
    spec = kit(job.variant)
    env = spec.env(job.files, job.variant, sumo_seed=job.seed, record=job.record, leader_guard=job.leader_guard, shield=job.shield)
    index = {a: i for i, a in enumerate(job.agents)}
    agent_of = {v: index[route_agent(v)] for v in env.possible_agents}  # vehicle -> its route agent's index
    buf = {k: [] for k in ("agent_idx", "state", "action", "reward", "next_state", "done")}  # see _as_array
    if job.shield:  # the masks each action was chosen under, and those of the next state (the learner's bootstrap)
        buf["allowed"], buf["next_allowed"] = [], []
    try:
        obs, infos = env.reset(seed=job.seed)
        while env.agents:
            ids = list(env.agents)
            # np.array of the rows, not np.stack (same array): numpy's per-call cost is what a decision pays here
            states = np.array([obs[v] for v in ids])
            agent_idx = np.fromiter(map(agent_of.__getitem__, ids), np.int64, len(ids))
            q = spec.q_values(job.params, states, agent_idx)
            allowed = None
            if job.shield:  # the best allowed action; exploring: a uniform draw among the allowed ones
                allowed = np.stack([infos[v]["action_mask"] for v in ids])
                buf["allowed"].append(allowed)
            action = kernels.epsilon_greedy(q, job.epsilon, bitgen, allowed)
            obs, rewards, terminated, truncated, infos = env.step(action)  # in the order of env.agents (= ids)
            buf["agent_idx"].append(agent_idx)
            buf["state"].append(states)
            buf["action"].append(action)
            buf["reward"] += map(rewards.get, ids, itertools.repeat(0.0))
            buf["next_state"] += map(obs.__getitem__, ids)
            buf["done"] += map(terminated.get, ids, itertools.repeat(False))
            if job.shield:
                buf["next_allowed"].append(np.stack([infos[v]["action_mask"] for v in ids]))
        counts = np.bincount([agent_of[v] for v in env.sim.tally.depart], minlength=len(job.agents))
        metrics = env.sim.metrics(job.n_vehicles)
        frames, collided, teleported, substeps = env.frames, set(env.sim.tally.collided), set(env.sim.tally.teleported), env.sim.tally.vehicle_substeps
    finally:
        env.close()
    transitions = {k: _as_array(k, v) for k, v in buf.items()}
    # each agent's rewards summed in the order they came, as np.add.at per decision would (bincount adds in input order)
    returns = np.bincount(transitions["agent_idx"].astype(np.int64), transitions["reward"], len(job.agents))
    with np.errstate(invalid="ignore", divide="ignore"):
        agent_return = np.where(counts > 0, returns / counts, np.nan)
    return EpisodeResult(transitions, agent_return, metrics, frames, collided, teleported, substeps)


# --- training ---------------------------------------------------------------------------------------


class ReplayBuffers:
    """One ring buffer per route agent, stored as [agent, slot, ...] arrays. It also keeps the target network's
    Q(s', ·) of every stored transition: the target network changes only every TARGET_EVERY_EPISODES episodes,
    so its forward pass is done once per new transition and per target update (`refresh`) rather than on every
    sampled batch of every gradient step (a third of a step's cost; the same values up to float rounding)."""

    def __init__(self, n_agents: int, state_dim: int, size: int, n_actions: int, masked: bool = False):
        self.capacity = size
        self.state = np.zeros((n_agents, size, state_dim), np.float32)
        self.next_state = np.zeros_like(self.state)
        self.action = np.zeros((n_agents, size), np.int64)
        self.reward = np.zeros((n_agents, size), np.float32)
        self.done = np.zeros((n_agents, size), np.float32)
        self.target_q = np.zeros((n_agents, size, n_actions), np.float32)  # target network's Q(next_state, ·)
        # under the safety layer: the actions allowed in next_state, the only ones the bootstrap may pick
        self.next_allowed = np.ones((n_agents, size, n_actions), bool) if masked else None
        self.size = np.zeros(n_agents, np.int64)
        self.head = np.zeros(n_agents, np.int64)

    def add(self, t: dict, target: nn.Module) -> None:
        new = np.bincount(t["agent_idx"], minlength=len(self.size))
        if not new.any():
            return
        for k in np.flatnonzero(new):
            sel = t["agent_idx"] == k
            slots = (self.head[k] + np.arange(new[k])) % self.capacity
            self.state[k, slots], self.next_state[k, slots] = t["state"][sel], t["next_state"][sel]
            self.action[k, slots], self.reward[k, slots], self.done[k, slots] = t["action"][sel], t["reward"][sel] * REWARD_SCALE, t["done"][sel]
            if self.next_allowed is not None:
                self.next_allowed[k, slots] = t["next_allowed"][sel]
        # the new slots of every agent, padded to the longest run with its last one: one batched forward pass
        slots = (self.head[:, None] + np.minimum(np.arange(new.max()), np.maximum(new - 1, 0)[:, None])) % self.capacity
        self._set_target_q(target, slots, np.arange(new.max()) < new[:, None])
        self.head = (self.head + new) % self.capacity
        self.size = np.minimum(self.size + new, self.capacity)

    def refresh(self, target: nn.Module, chunk: int = BATCH_SIZE) -> None:
        """Recompute the stored target Q after a target-network update, `chunk` slots per agent at a time."""
        filled = int(self.size.max())
        for start in range(0, filled, chunk):
            slots = np.tile(np.arange(start, min(start + chunk, filled)), (len(self.size), 1))
            self._set_target_q(target, slots, slots < self.size[:, None])

    def _set_target_q(self, target: nn.Module, slots: np.ndarray, valid: np.ndarray) -> None:
        rows = np.arange(len(self.size))[:, None]
        with torch.no_grad():
            q = target(torch.from_numpy(self.next_state[rows, slots])).numpy()
        k, j = np.nonzero(valid)
        self.target_q[k, slots[k, j]] = q[k, j]

    def state_dict(self) -> dict:
        """Every array as a tensor, the per-slot ones up to the fullest buffer (agents fill their slots from 0 up)."""
        filled = int(self.size.max())
        return {k: torch.from_numpy(np.ascontiguousarray(v[:, :filled] if v.ndim > 1 else v))
                for k, v in vars(self).items() if isinstance(v, np.ndarray)}

    def load_state_dict(self, saved: dict) -> None:
        for k, v in saved.items():
            array = getattr(self, k)
            if array.ndim > 1:
                array[:, :v.shape[1]] = v.numpy()
            else:  # size, head
                array[:] = v.numpy()

    def sample(self, rng: np.random.Generator, batch: int):
        """`batch` transitions of every agent (drawn with replacement); agents with an empty buffer are masked.
        The last item is the next states' allowed actions, None when the buffers are not masked."""
        n = len(self.size)
        slots = (rng.random((n, batch)) * np.maximum(self.size, 1)[:, None]).astype(np.int64)
        flat = (slots + np.arange(n)[:, None] * self.capacity).ravel()  # `take` on flat rows: 2-3x faster than a[rows, slots]
        masks = (self.next_allowed,) if self.next_allowed is not None else ()
        tensors = [torch.from_numpy(a.reshape(n * self.capacity, -1).take(flat, axis=0).reshape(n, batch, *a.shape[2:]))
                   for a in (self.state, self.action, self.reward, self.next_state, self.target_q, self.done, *masks)]
        next_allowed = tensors.pop() if masks else None
        return (*tensors, torch.from_numpy(self.size > 0), next_allowed)


@functools.lru_cache
def _learner_threads(n: int) -> ThreadPoolExecutor:
    return ThreadPoolExecutor(n, thread_name_prefix="learner")


def dqn_update(q: nn.Module, optimiser, batch, threads: int = 1) -> np.ndarray:
    """One double-DQN step for all route agents: y = r + γ (1 - done) Q_target(s', argmax_a Q(s', a)), with
    Q_target(s', ·) as stored by ReplayBuffers; under the safety layer the argmax runs over the actions allowed
    in s'. The agents' losses are independent, so their gradients are computed
    CHUNK_ROWS batch rows at a time (a few agents), which keeps the hidden activations in the CPU's cache: 2x faster
    for 40 agents at batch 2,500 than one pass over the whole stack. With `threads` > 1 the chunks run concurrently in
    that many threads (torch frees the GIL in its kernels; the episode workers wait meanwhile, so their cores are
    free): a chunk's backward adds exact zeros to the other agents' gradients, so the sum is the same bit for bit in
    any order and the result does not depend on the threads (tested)."""
    state, action, reward, next_state, target_q_next, done, has_data, next_allowed = batch
    n_agents, batch_size = action.shape
    # the chunks must not depend on the threads: at some batch sizes torch's kernels round differently for other chunk sizes
    per_chunk = max(CHUNK_ROWS // batch_size, 1)

    def chunk_loss(first: int) -> torch.Tensor:
        a = slice(first, first + per_chunk)
        with torch.no_grad():
            q_next = q(next_state[a], a)
            if next_allowed is not None:
                q_next = q_next.masked_fill(~next_allowed[a], -torch.inf)
            best_next = q_next.argmax(dim=2, keepdim=True)
            y = reward[a] + GAMMA * (1.0 - done[a]) * target_q_next[a].gather(2, best_next).squeeze(2)
        q_taken = q(state[a], a).gather(2, action[a, :, None]).squeeze(2)
        per_agent = ((q_taken - y) ** 2).mean(dim=1) * has_data[a]  # sum of per-agent MSE: agents stay independent
        per_agent.sum().backward()  # adds this chunk's agents' gradients; the others' stay untouched
        return per_agent.detach()

    optimiser.zero_grad()
    firsts = range(0, n_agents, per_chunk)
    losses = list(_learner_threads(threads).map(chunk_loss, firsts) if threads > 1 else map(chunk_loss, firsts))
    optimiser.step()
    return np.where(has_data.numpy(), torch.cat(losses).numpy(), np.nan)  # loss of each route agent


def numpy_params(q: RouteAgentsQ) -> dict[str, np.ndarray]:
    return {k: v.detach().numpy().copy() for k, v in q.state_dict().items()}


def share_untrained(params: dict[str, np.ndarray], agents: list[str], trained: np.ndarray) -> dict[str, np.ndarray]:
    """The weights with every route agent that never trained (trained[k] False: no transition in its replay buffer)
    replaced by the first trained agent of its route ('route:class'), if there is one. An untrained agent still has its
    random initial weights, yet it drives that route's vehicles of its class on other copies: on the demo's Sc1, 3 of
    the 12 heavy agents get no vehicle in the 2 training copies, and their greedy choice, the argmax of initial
    weights, held heavy vehicles at a standstill until SUMO teleported them (docs/history/urban.md, ninth session)."""
    route = np.unique([a.rpartition(":")[0] for a in agents], return_inverse=True)[1]
    done = np.flatnonzero(trained)
    routes_done, at = np.unique(route[done], return_index=True)  # each route's first trained agent
    first = np.full(route.max(initial=-1) + 1, -1)
    first[routes_done] = done[at]
    donor = np.where(~trained & (first[route] >= 0), first[route], np.arange(len(agents)))
    return {k: v[donor] for k, v in params.items()}


def epsilon_at(episode: int, episodes: int) -> float:
    explore = max(int(EXPLORATION_FRACTION * episodes), 1)
    return max(EPSILON_START * (1.0 - episode / explore), 0.0)


def _checkpoint(path: str, every_s: float, copies: list[tuple[ScenarioFiles, int]], **arguments) -> Checkpoint:
    """One run's checkpoint, fingerprinted by the arguments that decide its numbers and its training copies' files (the
    workers too: a round runs one episode per worker, and the learner as many threads)."""
    files = [file for f, _ in copies for file in (f.net, f.routes, f.vtypes("idm"), f.vtypes("krauss"))]
    return Checkpoint(path, fingerprint(files, copies=[(f.last_depart_s, f.max_speed_mps, n) for f, n in copies], **arguments), every_s)


def _progress_due(episode: int, episodes: int, since_last_line_s: float) -> bool:
    """A progress line after the first episode, every 10 % of them, the last, and at least every PROGRESS_EVERY_S."""
    return episode % max(episodes // 10, 1) == 0 or episode == episodes - 1 or since_last_line_s >= PROGRESS_EVERY_S


def _pace(done: int, left: int, seconds: float) -> str:
    """' (12.3 episodes/min, ~1 h 05 min left)' after `done` episodes in `seconds`; '' before the first minute."""
    if seconds < 60 or done <= 0:
        return ""
    per_min = 60 * done / seconds
    minutes = round(left / per_min)
    return f" ({per_min:.1f} episodes/min, ~{minutes // 60} h {minutes % 60:02d} min left)"


def train(
    copies: list[tuple[ScenarioFiles, int]],
    agents: list[str],
    variant: str,
    episodes: int,
    seed: int,
    run_parallel,
    log=print,
    leader_guard: bool = True,
    gradient_steps: int | None = None,
    shield: bool = False,
    checkpoint_path: str | None = None,
    checkpoint_every_s: float = 600.0,
) -> tuple[dict, list[dict]]:
    """Train the route agents on the training copies (episode k uses copy k mod len(copies)).

    `run_parallel(jobs)` runs EpisodeJobs (in worker processes) and returns their results in order; a
    round holds as many episodes as it has workers, all with the same weights. The gradient steps run in as many
    threads as there are workers (the workers wait meanwhile); the same seed gives the same weights and log.
    gradient_steps per episode: None = the variant's default. shield: the training episodes run under the env's safety
    layer (the agents act and bootstrap only over allowed actions; off by default: not the thesis, and measured no
    better, docs/urban.md). checkpoint_path: a file where the run's whole state (weights, Adam, replay buffers, random
    generator, log) is saved every `checkpoint_every_s` and at the end; a call that finds this run's checkpoint there goes
    on from it, to the same result as an uninterrupted run (models/urban/checkpoint.py). Returns (numpy weights, route
    agents that saw no vehicle sharing their route's trained one's: `share_untrained`; one log row per route agent and
    logged episode: see LOG_EPISODES)."""
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    rng = np.random.default_rng(seed)
    spec = kit(variant)
    q, target = spec.network(len(agents), spec.state_dim, gen), spec.network(len(agents), spec.state_dim, gen)
    target.load_state_dict(q.state_dict())
    optimiser = torch.optim.Adam(q.parameters(), lr=LEARNING_RATE)
    buffers = ReplayBuffers(len(agents), spec.state_dim, spec.buffer_size, spec.n_actions, masked=shield)
    steps = gradient_steps or spec.gradient_steps
    rows: list[dict] = []
    workers = getattr(run_parallel, "workers", 1)
    episode = 0
    stateful = {"q": q, "target": target, "optimiser": optimiser, "buffers": buffers}  # a checkpoint's parts, with episode, log, generator
    checkpoint = checkpoint_path and _checkpoint(
        checkpoint_path, checkpoint_every_s, copies, variant=variant, episodes=episodes, seed=seed, workers=workers,
        leader_guard=leader_guard, steps=steps, shield=shield, agents=agents)
    saved = checkpoint.load() if checkpoint else None
    if checkpoint and checkpoint.skipped:
        log(checkpoint.skipped)
    if saved and saved["done"]:
        log(f"{variant}: trained already ({checkpoint.path})")
        return {k: v.numpy() for k, v in saved["params"].items()}, saved["rows"]
    if saved:
        episode, rows, rng.bit_generator.state = saved["episode"], saved["rows"], saved["rng"]
        for key, part in stateful.items():
            part.load_state_dict(saved[key])
        log(f"{variant}: resumed at episode {episode}/{episodes} from {checkpoint.path}")
    first, started = episode, time.monotonic()  # the pace: this call's episodes over this call's time (also when resumed)
    last_line = started
    while episode < episodes:
        n = min(workers, episodes - episode)
        params = numpy_params(q)
        jobs = [
            EpisodeJob(copies[(episode + i) % len(copies)][0], variant, agents, params, epsilon_at(episode + i, episodes),
                       seed * 100_003 + episode + i, copies[(episode + i) % len(copies)][1], leader_guard=leader_guard, shield=shield)
            for i in range(n)
        ]
        for job, result in zip(jobs, run_parallel(jobs)):
            if len(result.transitions["agent_idx"]):
                buffers.add(result.transitions, target)
            batch = min(BATCH_SIZE, int(buffers.size.max()))  # early on, no bigger than the fullest buffer
            losses = np.mean([dqn_update(q, optimiser, buffers.sample(rng, batch), workers) for _ in range(steps)], axis=0)
            if (episode + 1) % TARGET_EVERY_EPISODES == 0:
                target.load_state_dict(q.state_dict())
                buffers.refresh(target)
            if episode % max(episodes // LOG_EPISODES, 1) == 0 or episode == episodes - 1:
                rows += [
                    {"agent": a, "episode": episode, "return": float(result.agent_return[k]), "epsilon": job.epsilon,
                     "loss": float(losses[k])}
                    for k, a in enumerate(agents)
                ]
            m = result.metrics
            if _progress_due(episode, episodes, time.monotonic() - last_line):
                log(f"{variant} episode {episode + 1}/{episodes}: ε={job.epsilon:.2f} collisions={m['collisions']} "
                    f"teleports={m['teleports']} arrived={m['arrived']}/{job.n_vehicles} travel={m['avg_travel_time_s']:.1f}s "
                    f"loss={np.nanmean(losses):.3f}{_pace(episode + 1 - first, episodes - episode - 1, time.monotonic() - started)}")
                last_line = time.monotonic()
            episode += 1
        if checkpoint and checkpoint.due() and episode < episodes:
            checkpoint.save({"done": False, "episode": episode, "rows": rows, "rng": rng.bit_generator.state,
                             **{key: part.state_dict() for key, part in stateful.items()}})
    params = share_untrained(numpy_params(q), agents, buffers.size > 0)
    if checkpoint:  # kept until the caller removes it: a re-run after a later crash skips this finished run
        checkpoint.save({"done": True, "params": {k: torch.from_numpy(v) for k, v in params.items()}, "rows": rows})
    return params, rows
