"""Reference solutions: the exact integer program (HiGHS) and first-come-first-served ground delays.

Integer program (minimum total delay under the capacity constraints; among the schedules with that delay, the
fewest regulated flights, d >= REGULATED_MIN, so that the reference's total delay and regulated count do not depend
on which of several equally short schedules a solver version finds; its per-flight delays, and so avg_delay_min,
still may: {5, 1, 1} and {4, 2, 1} tie on both):

    min  Σ_f Σ_d ((F + 1) · d + [d >= REGULATED_MIN]) · x_fd          F flights: the second term sums to at most F
    s.t. Σ_d x_fd = 1                                   every flight gets one delay d ∈ {0..MaxDelay}
         Σ_{(f,d): an entry of f delayed by d falls in sector-hour k} x_fd <= capacity_k     every k
         x_fd ∈ {0, 1}

Exact reductions: sector-hours that cannot exceed capacity whatever the delays get no row, and a
flight with no entry that can reach such a row is fixed at delay 0.
"""

import time

import highspy
from highspy.highs import _Highs
import numpy as np
from scipy import sparse

from models.dcb.problem import REGULATED_MIN, DCBProblem


class InfeasibleError(ValueError):
    """No delays within MaxDelay resolve every hotspot, or HiGHS did not prove optimality within its time limit."""


def solve_optimum(problem: DCBProblem, time_limit_s: float = 300.0) -> tuple[np.ndarray, float]:
    """Exact minimum-total-delay solution -> (delay per flight [min], solve time [s])."""
    started = time.perf_counter()
    rel = problem.relevant
    delays = np.arange(problem.max_delay_min + 1)
    flights = np.unique(problem.entry_flight[rel])
    col_of = np.full(problem.n_flights, -1)
    col_of[flights] = np.arange(flights.size)
    # entry e delayed by d lands in key(e, d); column of (flight, d) = col_of[flight] * D + d
    ent = np.repeat(rel, delays.size)
    d = np.tile(delays, rel.size)
    key = problem.entry_sector[ent] * problem.n_hours + ((problem.entry_min[ent] + d) // 60).astype(np.int64)
    col = col_of[problem.entry_flight[ent]] * delays.size + d
    rows, row_of_key = np.unique(key, return_inverse=True)
    # one entry may land twice in the same sector-hour only if the flight re-enters; count it twice (it is two entries)
    cap_rows = sparse.csr_matrix((np.ones(col.size), (row_of_key, col)), shape=(rows.size, flights.size * delays.size))
    assign = sparse.kron(sparse.eye(flights.size), np.ones((1, delays.size)), format="csr")
    a = sparse.vstack([assign, cap_rows]).tocsc()
    # the solver without highspy's Python wrapper, whose constructor makes HiGHS print its banner to C stdout before
    # output_flag can be set (in the middle of a run's progress lines); we use none of the wrapper's callbacks
    h = _Highs()
    h.setOptionValue("output_flag", False)
    h.setOptionValue("time_limit", float(time_limit_s))
    h.setOptionValue("random_seed", 0)
    h.setOptionValue("mip_rel_gap", 0.0)  # the objective is an integer: stop only at a proven optimum
    lp = highspy.HighsLp()
    lp.num_col_, lp.num_row_ = a.shape[1], a.shape[0]
    lp.col_cost_ = np.tile((flights.size + 1) * delays + (delays >= REGULATED_MIN), flights.size).astype(float)
    lp.col_lower_, lp.col_upper_ = np.zeros(a.shape[1]), np.ones(a.shape[1])
    lp.row_lower_ = np.concatenate([np.ones(flights.size), np.full(rows.size, -highspy.kHighsInf)])
    lp.row_upper_ = np.concatenate([np.ones(flights.size), problem.capacity[rows].astype(float)])
    lp.a_matrix_.format_ = highspy.MatrixFormat.kColwise
    lp.a_matrix_.start_, lp.a_matrix_.index_, lp.a_matrix_.value_ = a.indptr, a.indices, a.data
    lp.integrality_ = [highspy.HighsVarType.kInteger] * a.shape[1]
    h.passModel(lp)
    h.run()
    status = h.getModelStatus()
    if status != highspy.HighsModelStatus.kOptimal:
        raise InfeasibleError(f"integer program: {h.modelStatusToString(status)} (MaxDelay {problem.max_delay_min} min)")
    x = np.asarray(h.getSolution().col_value).reshape(flights.size, delays.size)
    delay = np.zeros(problem.n_flights, dtype=np.int64)
    delay[flights] = x.argmax(axis=1)
    return delay, time.perf_counter() - started


def fcfs(problem: DCBProblem, max_rounds: int = 1000) -> np.ndarray:
    """First-come-first-served ground delays, as a ground-delay programme assigns slots today.

    Repeatedly, in every hotspot the first `capacity` entries keep their time and each later one is
    delayed just into the next hour; a flight takes its largest such delay. Delays are not capped
    at MaxDelay. Stops when no hotspot is left; InfeasibleError when that needs delays past the problem's hour grid."""
    delay = np.zeros(problem.n_flights, dtype=np.int64)
    flight, sector = problem.entry_flight, problem.entry_sector
    for _ in range(max_rounds):
        # keys of its own: uncapped delays can run past the problem's hour grid
        t = problem.entry_min + delay[flight]
        hour = (t // 60).astype(np.int64)
        if hour.max() >= problem.n_hours - 1:  # capacities far below the demand: no FCFS schedule the results can evaluate
            raise InfeasibleError(f"FCFS needs delays of up to {delay.max()} min, past the problem's {problem.n_hours}-hour grid: "
                                  "the capacities cannot carry the day's demand")
        key = sector * (int(hour.max()) + 1) + hour
        order = np.lexsort((t, key))
        ks = key[order]
        rank = np.arange(ks.size) - np.searchsorted(ks, ks, side="left")  # position within its sector-hour
        late = order[rank >= problem.sector_capacity[sector[order]]]
        if late.size == 0:
            return delay
        needed = np.ceil((hour[late] + 1) * 60 - t[late]).astype(np.int64)
        extra = np.zeros(problem.n_flights, dtype=np.int64)
        np.maximum.at(extra, flight[late], needed)
        delay += extra
    raise RuntimeError(f"FCFS did not converge in {max_rounds} rounds")
