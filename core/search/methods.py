"""The search methods, each a function of (state, threshold) that returns why it stopped.

    hybrid:  ICP -> E < threshold? stop : anneal from there -> better point? ICP again : stop (paper Fig. 6)
    icp:     ICP alone
    sa:      simplex annealing alone, from the initial pose down to the minimum temperature
    icp-restarts: ICP from random poses within the initial uncertainty until E < threshold or the
             restart budget runs out (Besl and McKay's suggestion, paper section 3)
    basin-hopping: beyond the paper. Annealing's job in the hybrid, new starting points for ICP, done
             by random hops from the best local minimum found so far, each followed by ICP; a lower
             minimum is kept (monotonic basin hopping, Wales and Doye 1997). Where the hybrid's
             annealing must find a pose *lower* than ICP's minimum, a hop only has to land in the
             catchment of a lower one: on the bowl, whose true well is narrow and sits at the end of a
             long valley (a bowl slides over itself by tilting), that is what succeeds.

A new method is a function added to ``METHODS`` (and its name to ``core.config.METHODS``).
"""

from __future__ import annotations

from collections.abc import Callable

from ..result import Stop, StopReason
from .state import SearchState

Method = Callable[[SearchState, float], Stop]


def hybrid(state: SearchState, threshold: float) -> Stop:
    T, E = state.first_icp(threshold)
    while True:
        if E < threshold:
            return Stop(StopReason.BELOW_THRESHOLD)
        state.mark_local_minimum(T, E)
        T_sa, E_sa, better = state.sa(T, E, E * (1 - state.config.search.min_gain), state.config.anneal)
        if not better:
            return Stop(StopReason.NO_BETTER_POINT)
        T, E = state.icp(T_sa)


def icp_alone(state: SearchState, threshold: float) -> Stop:
    T, E = state.icp(state.start, bounded=False)  # the classic baseline walks wherever E leads
    if E >= threshold:
        state.mark_local_minimum(T, E)
        return Stop(StopReason.ICP_ABOVE_THRESHOLD)
    return Stop(StopReason.BELOW_THRESHOLD)


def sa_alone(state: SearchState, threshold: float) -> Stop:
    E0 = state.error(state.start)
    state.sa(state.start, E0, None, state.config.sa_alone)
    return Stop(StopReason.MIN_TEMPERATURE)


def icp_restarts(state: SearchState, threshold: float) -> Stop:
    budget = state.config.restarts
    for k in range(budget):
        T, E = state.icp(state.random_step(state.start, 1.0)) if k else state.first_icp(threshold)
        if E < threshold:
            return Stop(StopReason.BELOW_THRESHOLD, f"error below threshold after {k + 1} ICP runs")
        state.mark_local_minimum(T, E)
    return Stop(StopReason.RESTARTS_SPENT, f"restart budget ({budget} ICP runs) spent")


def basin_hopping(state: SearchState, threshold: float) -> Stop:
    T, E = state.first_icp(threshold)
    if E >= threshold:
        state.mark_local_minimum(T, E)
    # Refining (on the overlap re-cut at the pose found, with the small uncertainty left) always hops
    # a few times: the threshold sits above near-misses round the true well (see SearchConfig.confirm_hops).
    budget = min(state.config.search.confirm_hops, state.config.hops) if state.refining else state.config.hops
    for hop in range(budget):
        if E < threshold and not state.refining:
            return Stop(StopReason.BELOW_THRESHOLD, f"error below threshold ({hop} hops)")
        T_hop = state.random_step(T, state.config.hop_size)
        if not state.inside(T_hop):
            continue
        state.hop(T_hop)  # a hop counts as an annealing iteration: a stochastic move
        T_new, E_new = state.icp(T_hop)
        if E_new >= threshold:
            state.mark_local_minimum(T_new, E_new)
        if E_new < E:
            T, E = T_new, E_new
    if E < threshold:
        return Stop(StopReason.BELOW_THRESHOLD)
    return Stop(StopReason.HOPS_SPENT, f"hop budget ({budget} hops) spent")


METHODS: dict[str, Method] = {"hybrid": hybrid, "icp": icp_alone, "sa": sa_alone, "icp-restarts": icp_restarts,
                              "basin-hopping": basin_hopping}
