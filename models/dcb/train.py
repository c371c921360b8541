"""Training loop shared by all learners, the abstraction levels, and the six methods (thesis §5.4-5.6).

Episode: all delays start at 0. Every step, each flight that is in a hotspot (h_i > 0) and below
MaxDelay chooses ε-greedily to add one more delay step or not; flights in no hotspot keep their
delay (the thesis's deterministic rule). Demand, hotspots and rewards are recomputed for the new
delays and every acting agent (or every graph edge) is updated at once. The episode ends when no
flight can act (no hotspot left) or after MaxDelay / step steps. The step's parts are numba kernels
(models/dcb/kernels.py); MIRL, CMARL and their hierarchical variants with the thesis state and reward run their whole
episode as one kernel call, bit for bit the episode of the step-by-step loop (tests/dcb/test_compiled.py).

Local state s_i = (d_i, h_i) (Eq 5.1), h_i capped at H_CAP. An abstraction level (§5.5.2) maps
d_i to d_i // state_step (φ_L, Eq 5.11) and lets an action add `action_step` minutes:

    method    learner       abstract level (state_step, action_step) -> ground (1, 1)
    MIRL      independent   -
    CMARL     coordinated   -
    HCMARL    coordinated   (10, 10)    state + temporal abstraction (thesis: I = 10 min)
    stHMIRL   independent   (10, 10)    state + temporal abstraction
    sHMIRL    independent   (10, 1)     state abstraction only
    tHMIRL    independent   (1, 10)     temporal abstraction only

Options beyond the thesis (defaults: the thesis's, but for the read-out), see docs/dcb.md for what they change:
- state="extended": s_i = (d_i, h_i, x_i), x_i = 1 if one of the flight's hot entries is among the
  `demand - capacity` entries of its hotspot closest to the end of their hour (DCBProblem.movers);
- reward="difference": each flight is rewarded with what its own action changed in the day's total
  of Eq 5.2 (DCBProblem.difference_reward) instead of its local Eq 5.2 reward; reward="overload": the
  same for the day's overload, entries beyond capacity (DCBProblem.overload_reward);
- hold="depart" (every method, thesis state and reward): §5.4's "the agent is responsible for
  distributing delay units to the corresponding flight until it departs ... Afterwards ... without the possibility to
  receive additional delay" read literally. A flight that holds, or whose delay took it out of every hotspot, departs:
  it never acts again in the episode, and its last action is valued by the rewards it still collects until the episode
  ends (its congestion as the others move) instead of by Q of a state it will act in. With hold="wait" (default) a
  flight that holds faces the same state at the next step, so "hold" in a hotspot nobody clears yet bootstraps from
  itself (-81 · TDC per step) and every flight of a hotspot learns to delay (docs/dcb.md, "What we learned").
  CMARL / HCMARL: a departed flight stays in its hotspots' coordination graph as a peer whose action is 0 (Eq 5.7's
  bootstrap and Eq 5.9's max range over the acting flights' actions only); an edge keeps Eq 5.7 while one of its
  flights acts, and once it is done (both departed, or one departed and in no hotspot) its last joint action is valued
  by the two flights' shares of the rewards they collect until the episode ends (models/dcb/cmarl.py);
- c_plus: the value of C₊ (Eq 5.3, "a large positive constant"; ours, default 100); with hold="depart" a departed
  flight collects it at every step it spends out of hotspots, so it weighs how much leaving a hotspot is worth.

Q-values of the abstract level initialise the ground level (Q_ground(s) = Q_abstract(φ(s))), which
then trains with exploration starting at ε = 0.7. Two candidate schedules come out: the greedy (ε = 0)
rollout of the final ground-level policy and the best ground-level episode met in training (fewest
hotspots, then least total delay). readout="repair" (default) passes both through `readout.polish`
(hotspots left resolved first come first served within MaxDelay, then delay no hotspot needs trimmed);
readout="best_episode" takes them as they are. The better one (fewest hotspots, then least delay; ties:
greedy) is returned: an operator keeps the best schedule found. `TrainResult.source` says which one;
`greedy_delay` / `greedy_hotspots` always describe the raw greedy rollout, so the policy itself can
be judged apart from the read-out (dcb_delays' policy_delay_min, dcb_results' policy_* columns).
"""

import time
from dataclasses import dataclass, replace

import numpy as np

from models.dcb import kernels
from models.dcb.cmarl import GOLDEN, TABLE_BITS, CoordinatedQ
from models.dcb.mirl import LEARNING_RATE, IndependentQ
from models.dcb.problem import AVG_DELAY_COST_EUR_PER_MIN, C_PLUS, DCBProblem
from models.dcb.readout import polish

EPISODES = 15_000  # per level (thesis §5.6.2)
EPSILON_START = 0.9  # ε at the first (abstract or only) level
EPSILON_GROUND_START = 0.7  # ε at the ground level of a hierarchical method
EPSILON_DECAY = 0.01  # ε decreases by this ...
EPSILON_EVERY = 120  # ... every this many episodes (of 15,000; scaled to shorter runs)
H_CAP = 3  # h_i states: 0, 1, 2, >= 3 hotspots
ABSTRACT_STEP_MIN = 10  # I, the abstract level's interval
STATES = {"thesis": 1, "extended": 2}  # local state -> values of its extra component x_i
# Eq 5.2-5.4 per flight; its difference reward (DCBProblem.difference_reward); the difference reward of the overload
# (DCBProblem.overload_reward)
REWARDS = ("thesis", "difference", "overload")
READOUTS = ("repair", "best_episode")  # the solution read out of a trained policy, see the module docstring
HOLDS = ("wait", "depart")  # what holding means for a flight in a hotspot, see the module docstring
DEPART_ONLY = "DCB hold 'depart' is implemented with the thesis state and reward only (the compiled episodes of MIRL's and CMARL's learners)"


@dataclass(frozen=True)
class Level:
    state_step: int  # minutes of delay per abstract state (φ_L)
    action_step: int  # minutes added by the "delay" action
    n_extra: int = 1  # values of the extended state's extra component x_i (1: the thesis state)

    def n_states(self, max_delay: int) -> int:
        return (max_delay // self.state_step + 1) * (H_CAP + 1) * self.n_extra

    def state(self, delay_min: np.ndarray, hotspots: np.ndarray, extra: np.ndarray | None = None) -> np.ndarray:
        """s_i of every flight from d_i, h_i and (extended state) x_i."""
        return kernels.local_state(delay_min, hotspots, delay_min[:0] if extra is None else extra, self.state_step, self.n_extra, H_CAP)

    def state_map(self, max_delay: int) -> np.ndarray:
        """φ: ground state index -> this level's state index."""
        ground = np.arange(GROUND.n_states(max_delay) * self.n_extra)
        dh = ground // self.n_extra
        return self.state(dh // (H_CAP + 1), dh % (H_CAP + 1), ground % self.n_extra)


GROUND = Level(1, 1)
METHODS = {
    "MIRL": (IndependentQ, None),
    "CMARL": (CoordinatedQ, None),
    "HCMARL": (CoordinatedQ, Level(ABSTRACT_STEP_MIN, ABSTRACT_STEP_MIN)),
    "stHMIRL": (IndependentQ, Level(ABSTRACT_STEP_MIN, ABSTRACT_STEP_MIN)),
    "sHMIRL": (IndependentQ, Level(ABSTRACT_STEP_MIN, 1)),
    "tHMIRL": (IndependentQ, Level(1, ABSTRACT_STEP_MIN)),
}


@dataclass
class TrainResult:
    delay_min: np.ndarray  # [flight] the returned solution (see `source`)
    hotspots_left: int
    runtime_s: float
    episodes: int  # over all levels
    curve: np.ndarray  # [episode, 3]: episode, hotspots left and total delay [min], every 50th training episode
    source: str  # "greedy" (rollout of the final policy) or "best_episode" (best ground-level training episode), repaired or not
    greedy_delay: np.ndarray  # [flight] the greedy rollout of the final policy, before any read-out (whatever was returned)
    greedy_hotspots: int  # hotspots it leaves

    @property
    def greedy_delay_min(self) -> int:
        return int(self.greedy_delay.sum())


def epsilon(episode: int, start: float, episodes: int) -> float:
    every = max(1, round(EPSILON_EVERY * episodes / EPISODES))
    return max(0.0, start - EPSILON_DECAY * (episode // every))


def local_state(problem: DCBProblem, level: Level, delay: np.ndarray, ev) -> np.ndarray:
    """s_i = (d_i, h_i), or (d_i, h_i, x_i) with x_i = `problem.movers` for the extended state."""
    return level.state(delay, ev.hotspots_per_flight, problem.movers(delay, ev) if level.n_extra > 1 else None)


def _episode_tail(problem: DCBProblem, learner, level: Level, eps: float, learn: bool, c_plus: float) -> tuple:
    """The compiled episodes' arguments after their learner's and the start's: ε, steps, the level, η, γ, the delay costs,
    the entries `kernels.evaluate` reads and the reward's constants."""
    return (eps, problem.max_delay_min // level.action_step, level.action_step, level.state_step, learn, learner.lr, learner.gamma,
            problem.delay_cost, problem.kernel_entries(), H_CAP, AVG_DELAY_COST_EUR_PER_MIN, c_plus)


def _independent_episode(problem: DCBProblem, learner: IndependentQ, level: Level, eps: float, rng: np.random.Generator, learn: bool,
                         delay: np.ndarray, state: np.ndarray, ev, c_plus: float, hold: str) -> tuple[np.ndarray, int]:
    """`run_episode` for MIRL and its hierarchical variants with the thesis state and reward: one kernel call for the
    whole episode (`kernels.independent_episode`, ~20-30 µs per step on the full day; the loop's kernel calls part by
    part cost ~70 µs, mostly call overhead and the numpy draws)."""
    delay, hotspots = kernels.independent_episode(rng, learner.q, delay, state, (ev.hotspots_per_flight > 0).nonzero()[0], ev.hotspots,
                                                  *_episode_tail(problem, learner, level, eps, learn, c_plus), hold == "depart")
    return delay, int(hotspots)


def _coordinated_episode(problem: DCBProblem, learner: CoordinatedQ, level: Level, eps: float, rng: np.random.Generator, learn: bool,
                         delay: np.ndarray, state: np.ndarray, ev, c_plus: float, hold: str) -> tuple[np.ndarray, int]:
    """`run_episode` for CMARL and HCMARL with the thesis state and reward: one kernel call for the whole episode
    (`kernels.coordinated_episode`)."""
    delay, hotspots = kernels.coordinated_episode(rng, *learner.lookup, GOLDEN, TABLE_BITS, delay, state, (ev.hotspots_per_flight > 0).nonzero()[0],
                                                  ev.hot_key, ev.hot_flight, ev.hotspots, *_episode_tail(problem, learner, level, eps, learn, c_plus),
                                                  hold == "depart")
    return delay, int(hotspots)


def run_episode(problem: DCBProblem, learner, level: Level, eps: float, rng: np.random.Generator, learn: bool = True,
                reward: str = "thesis", hold: str = "wait", c_plus: float = C_PLUS) -> tuple[np.ndarray, int]:
    """One episode from zero delays; returns the final delays [min] and the hotspots they leave. hold: "wait" (a flight
    that holds acts again at the next step while it is in a hotspot) or "depart" (see the module docstring); c_plus: C₊ of
    Eq 5.3."""
    n_states = level.n_states(problem.max_delay_min)
    if isinstance(learner, IndependentQ | CoordinatedQ) and (learner.n_flights != problem.n_flights or learner.n_states < n_states):
        # the kernels index by flight and state unchecked (numba has no bounds check): a short table would be read and written past its rows
        raise ValueError(f"Q table of {learner.n_flights} flights × {learner.n_states} states: this problem and level need "
                         f"{problem.n_flights} × {n_states}")
    delay = np.zeros(problem.n_flights, dtype=np.int64)
    ev = problem.evaluate(delay)
    state = local_state(problem, level, delay, ev)
    # MIRL, CMARL with the thesis state and reward: the same episode as the loop below, compiled whole (any other
    # learner type, a subclass or a wrapper included, takes the loop: its values and update are called)
    compiled = {IndependentQ: _independent_episode, CoordinatedQ: _coordinated_episode}.get(type(learner))
    takes_compiled = compiled is not None and level.n_extra == 1 and (reward == "thesis" or not learn)
    if hold == "depart" and not takes_compiled:  # only the compiled episodes depart
        raise ValueError(DEPART_ONLY)
    if takes_compiled:
        return compiled(problem, learner, level, eps, rng, learn, delay, state, ev, c_plus, hold)
    # every flight in a hotspot acts: at step t < MaxDelay // step all delays are <= t · step, so one more step stays within MaxDelay
    for _ in range(problem.max_delay_min // level.action_step):
        agents = (ev.hotspots_per_flight > 0).nonzero()[0]  # nonzero of a bool array: ~1.5x faster than of the counts
        if agents.size == 0:
            break
        q = learner.values(state, agents, ev)
        # both draws every step, in this order (the same seed gives the same delays as ever)
        explore_draw, coin = rng.random(agents.size), rng.integers(0, 2, agents.size)
        action, added, delay = kernels.act(delay, agents, q, explore_draw, coin, eps, level.action_step)
        before, ev = ev, problem.evaluate(delay)
        next_state = local_state(problem, level, delay, ev)
        if learn:
            if reward == "thesis":
                r = problem.reward(delay, ev, c_plus)
            else:
                r = (problem.difference_reward if reward == "difference" else problem.overload_reward)(added, before, ev)
            learner.update(state, action, r, next_state, agents)
        state = next_state
    return delay, ev.hotspots


def _make(learner_cls, problem: DCBProblem, n_states: int, lr: float):
    if learner_cls is CoordinatedQ:
        return CoordinatedQ(problem.n_flights, n_states, lr=lr)
    return IndependentQ(problem.n_flights, n_states, lr=lr)


def check_options(state: str, reward: str, learning_rate: float, readout: str, hold: str = "wait", c_plus: float = C_PLUS) -> None:
    """One line for an option `train` cannot use (dcb_delays asks before it starts any training)."""
    if state not in STATES:
        raise ValueError(f"unknown DCB local state {state!r}: expected one of {', '.join(STATES)}")
    if reward not in REWARDS:
        raise ValueError(f"unknown DCB reward {reward!r}: expected one of {', '.join(REWARDS)}")
    if readout not in READOUTS:
        raise ValueError(f"unknown DCB read-out {readout!r}: expected one of {', '.join(READOUTS)}")
    if not 0 < learning_rate <= 1:
        raise ValueError(f"DCB learning rate {learning_rate} is outside (0, 1]")
    if hold not in HOLDS:
        raise ValueError(f"unknown DCB hold {hold!r}: expected one of {', '.join(HOLDS)}")
    if not c_plus > 0:
        raise ValueError(f"DCB C+ {c_plus} is not positive (Eq 5.3: a large positive constant)")
    if hold == "depart" and (state != "thesis" or reward != "thesis"):
        raise ValueError(DEPART_ONLY)


def train(problem: DCBProblem, method: str, seed: int, episodes: int = EPISODES, state: str = "thesis",
          reward: str = "thesis", learning_rate: float = LEARNING_RATE, readout: str = "repair", hold: str = "wait",
          c_plus: float = C_PLUS) -> TrainResult:
    """Train `method` on `problem` (`episodes` per level) and return its solution (greedy rollout or best episode).

    state: "thesis" (d_i, h_i) or "extended" (d_i, h_i, x_i), see `local_state`; reward: "thesis" (Eq 5.2-5.4
    per flight), "difference" (`DCBProblem.difference_reward`) or "overload" (`DCBProblem.overload_reward`); learning_rate:
    η of Eq 5.6 / 5.7 (thesis 0.01); readout: "repair" (greedy rollout and best episode each through `readout.polish`)
    or "best_episode" (the two as they are); hold: "wait" or "depart" (module docstring); c_plus: C₊ of Eq 5.3."""
    check_options(state, reward, learning_rate, readout, hold, c_plus)
    learner_cls, abstract = METHODS[method]
    ground = replace(GROUND, n_extra=STATES[state])
    abstract = abstract and replace(abstract, n_extra=STATES[state])
    rng = np.random.default_rng(seed)
    started = time.perf_counter()
    curve = []
    levels = [(abstract, EPSILON_START), (ground, EPSILON_GROUND_START)] if abstract else [(ground, EPSILON_START)]
    learner, best, n = None, (np.inf, np.inf, None), 0
    for level, eps0 in levels:
        n_states = level.n_states(problem.max_delay_min)
        learner = _make(learner_cls, problem, n_states, learning_rate) if learner is None else learner.transferred(n_states, abstract.state_map(problem.max_delay_min))
        for e in range(episodes):
            delay, hot = run_episode(problem, learner, level, epsilon(e, eps0, episodes), rng, reward=reward, hold=hold, c_plus=c_plus)
            if level is ground and (hot, delay.sum()) < best[:2]:
                best = (hot, delay.sum(), delay)
            if e % 50 == 0 or e == episodes - 1:
                curve.append((n, hot, int(delay.sum())))
            n += 1
    delay, hot = run_episode(problem, learner, ground, 0.0, rng, learn=False, hold=hold)
    greedy = (delay, int(hot))
    candidates = {"greedy": delay} if best[2] is None else {"greedy": delay, "best_episode": best[2]}  # None: no episode trained
    if readout == "repair":
        candidates = {k: polish(problem, d) for k, d in candidates.items()}
    # fewest hotspots, then least delay; ties keep the greedy rollout (dicts keep their order, min the first)
    score = {k: (problem.evaluate(d).hotspots, d.sum()) for k, d in candidates.items()}
    source = min(score, key=score.get)
    delay, (hot, _) = candidates[source], score[source]
    return TrainResult(delay, int(hot), time.perf_counter() - started, episodes * len(levels), np.asarray(curve), source, *greedy)


def train_job(job: tuple) -> TrainResult:
    """`train` for a worker process (models.parallel.ProcessPool): (problem, method, seed, episodes, options)."""
    problem, method, seed, episodes, options = job
    return train(problem, method, seed, episodes, **options)
