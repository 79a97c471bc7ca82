"""GNSS receiver latency by profile likelihood.

A fix stamped t is where the antenna was at t - tau. At constant speed that is a constant
along-track offset (a position state absorbs it), at constant acceleration a velocity offset
as well: only changes of acceleration (speeding up, braking, turns) show the latency, and a
recursive filter whose latency is a state sees them weakly (comma2k19: 0.027 +- 0.054 s from a
0.1 s prior std, the truth ~0.06-0.08 s). Here the whole filter is run with the latency fixed
at a grid of values; the negative log-likelihood of all its innovations (the prediction-error
decomposition) is the profile, its minimum the estimate and its curvature the uncertainty.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


@dataclass
class LatencyProfile:
    tau_s: float
    std_s: float  # from the curvature of the cost; inf when the cost is flat
    at_limit: bool  # the minimum is at an end of the search range
    taus: list = field(default_factory=list)
    costs: list = field(default_factory=list)  # cost at each tau (prior included), minimum subtracted
    gnss_noise_scale: float = 1.0  # the fixes' stated noise times this in the profile's passes

    def summary(self) -> dict:
        return {"method": "profile likelihood", "latency_s": round(self.tau_s, 4),
                "latency_std_s": round(self.std_s, 4) if np.isfinite(self.std_s) else None,
                "at_search_limit": self.at_limit, "gnss_noise_scale": round(self.gnss_noise_scale, 3),
                "profile": [[round(t, 4), round(c, 3)] for t, c in zip(self.taus, self.costs)]}


def profile_latency(cost, lo: float, hi: float, *, step: float = 0.05, prior=None) -> LatencyProfile:
    """Minimise cost(tau) (a negative log-likelihood) over [lo, hi].

    A grid of `step`, then the parabola through the best point and its neighbours (least
    squares over up to 5 points within 2 steps) gives the minimum and the curvature; the
    minimum is evaluated once more and kept if it is lower. prior = (mean, std) adds
    0.5 ((tau - mean) / std)^2."""
    def total(t):
        c = float(cost(t))
        if prior is not None and prior[1] > 0:
            c += 0.5 * ((t - prior[0]) / prior[1]) ** 2
        return c

    n = max(int(np.ceil((hi - lo) / step - 1e-9)), 2)
    taus = list(np.linspace(lo, hi, n + 1))
    costs = [total(t) for t in taus]
    k = int(np.argmin(costs))
    tau, std, at_limit = taus[k], np.inf, k in (0, len(taus) - 1)
    near = [i for i in range(len(taus)) if abs(taus[i] - taus[k]) <= 2 * step + 1e-9]
    if len(near) >= 3:
        x = np.array([taus[i] for i in near]) - taus[k]
        a, b, _ = np.polyfit(x, [costs[i] for i in near], 2)
        if a > 0:
            std = float(1.0 / np.sqrt(2.0 * a))  # cost = 0.5 (tau - tau0)^2 / std^2 + const
            t_new = float(np.clip(taus[k] - b / (2 * a), lo, hi))
            if not at_limit and abs(t_new - taus[k]) > 1e-4:
                c_new = total(t_new)
                taus.append(t_new)
                costs.append(c_new)
                if c_new <= costs[k]:
                    tau = t_new
    order = np.argsort(taus)
    cmin = min(costs)
    return LatencyProfile(float(tau), std, at_limit, [float(taus[i]) for i in order],
                          [float(costs[i] - cmin) for i in order])
