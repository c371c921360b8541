"""Reading a schedule out of a trained policy: repair the hotspots it leaves, then trim the delay no hotspot needs.

Our addition, not the thesis's (docs/dcb.md, "Returned solution"). Two diagnosed failure modes of the
learned schedules are mended here:

* the greedy policy leaves hotspots, most of them ones whose resolution needs two flights to move together
  (a flight pushed out of a full hour lands in the next full hour); `repair` resolves them first come,
  first served on top of the learned delays, within MaxDelay;
* every flight of a hotspot acts at once, so flights delay in lockstep until enough of them cross the
  hour boundary: most of the learned delay sits on flights whose delay no hotspot needs (on cap95 ~300
  flights the optimum leaves at 0). `trim` lowers each delayed flight to its least delay at which every
  one of its entries still fits its sector-hour's capacity.

Both keep MaxDelay; `trim` never adds a hotspot. `repair` is a heuristic: it stops when no entry beyond
capacity can move any more, and a push can drop a flight's other entries into full sector-hours, so it
may leave (or even add) hotspots another schedule would avoid; `polish` therefore keeps the input, trimmed,
when repairing does not leave fewer hotspots. They use the entries that can ever be hot within MaxDelay
(`DCBProblem.relevant`), which decide every hotspot exactly.
"""

import numpy as np

from models.dcb.problem import DCBProblem

TRIM_PASSES = 5  # trimming one flight can free a slot for another; further passes rarely change anything


def _check_range(problem: DCBProblem, delay_min: np.ndarray) -> None:
    # the relevant entries are those that can be hot for delays within [0, MaxDelay]; outside it they miss some
    if delay_min.size and not (delay_min.min() >= 0 and delay_min.max() <= problem.max_delay_min):
        raise ValueError(f"delays must lie in [0, {problem.max_delay_min}] min, got {delay_min.min()}..{delay_min.max()}")


def repair(problem: DCBProblem, delay_min: np.ndarray) -> np.ndarray:
    """Resolve the hotspots `delay_min` leaves by FCFS on top of it: in every hotspot the entries that cannot
    leave their hour within MaxDelay, then the earliest, keep their time; each later one is pushed just into
    the next hour (its flight takes the largest such push); repeated until nothing more can move."""
    _check_range(problem, delay_min)
    e = problem.relevant_entries
    delay = delay_min.copy()
    cap = problem.capacity
    while True:
        t = e.whole_min + delay[e.flight]
        key, needed = e.key_base + t // 60, 60 - t % 60  # minutes to reach the next hour
        movable = delay[e.flight] + needed <= problem.max_delay_min
        order = np.lexsort((t, movable, key))  # within a sector-hour: immovable entries first, then first come
        ks = key[order]
        rank = np.arange(ks.size) - np.searchsorted(ks, ks, side="left")
        late = order[(rank >= cap[ks]) & movable[order]]
        if late.size == 0:
            return delay
        extra = np.zeros_like(delay)
        np.maximum.at(extra, e.flight[late], needed[late])
        delay += extra


def trim(problem: DCBProblem, delay_min: np.ndarray) -> np.ndarray:
    """Lower every delayed flight, largest delay first, to its least delay at which each of its entries fits
    its sector-hour (count ≤ capacity with the other flights where they are); passes until nothing changes (at most TRIM_PASSES).

    One flight at a time, as each move changes the counts the next one sees; the candidates of one flight
    (every delay below its own) are checked at once."""
    _check_range(problem, delay_min)
    e = problem.relevant_entries
    delay = delay_min.copy()
    by_flight = np.argsort(e.flight, kind="stable")
    start = np.searchsorted(e.flight[by_flight], np.arange(problem.n_flights + 1))
    delay[(delay > 0) & (start[1:] == start[:-1])] = 0  # no entry that can ever be hot: no delay is needed
    key = e.keys(delay)
    counts = np.bincount(key, minlength=problem.capacity.size)
    for _ in range(TRIM_PASSES):
        changed = False
        for f in np.argsort(-delay, kind="stable")[: np.count_nonzero(delay)]:
            idx = by_flight[start[f]:start[f + 1]]
            k = e.key_base[idx] + (e.whole_min[idx] + np.arange(delay[f])[:, None]) // 60  # [candidate delay, entry]
            np.subtract.at(counts, key[idx], 1)
            own = (k[:, :, None] == k[:, None, :]).sum(axis=2)  # a flight re-entering a sector within the hour counts twice
            fits = (counts[k] + own <= problem.capacity[k]).all(axis=1)
            if fits.any():
                delay[f] = np.argmax(fits)
                key[idx] = k[delay[f]]
                changed = True
            np.add.at(counts, key[idx], 1)
        if not changed:
            break
    return delay


def polish(problem: DCBProblem, delay_min: np.ndarray) -> np.ndarray:
    """`repair`, then `trim`; or `trim` alone where that leaves fewer hotspots (or as many, with less delay):
    never more hotspots than `delay_min` has."""
    repaired, kept = trim(problem, repair(problem, delay_min)), trim(problem, delay_min)
    score = lambda d: (problem.evaluate(d).hotspots, int(d.sum()))  # noqa: E731
    return repaired if score(repaired) <= score(kept) else kept


def readout_only(problem: DCBProblem) -> np.ndarray:
    """`polish` of zero delays: the read-out with no learned policy at all, the reference a learner must beat."""
    return polish(problem, np.zeros(problem.n_flights, dtype=np.int64))
