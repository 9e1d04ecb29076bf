"""A logger's arrival times for a sensor's samples, seeded: polls, a start-up backlog, a
mid-file stall, lost samples (tests of gateway/core/retiming.py and `adxlgw import
--arrival-col`)."""
import numpy as np

TRANSFER_S = 0.0025  # one sample's transfer when a backlog is flushed (the loggers' 2.5 ms)


def bursty_arrivals(seed, n=3000, period_s=0.010, lost=((700, 1), (1500, 3), (2200, 5)),
                    backlog=300, stall=(1800, 0.3)):
    """True sample times and a logger's arrival times for them, seeded.

    The sensor ticks every period_s; the samples at the given rows are preceded by lost ones.
    The host polls every 12–17 ms and receives all samples taken before the poll, one per
    2.5 ms; it starts polling only when sample `backlog` is taken (a start-up backlog) and
    stops for stall[1] s at sample stall[0] (a mid-file stall). Jitter: 0–0.3 ms.
    """
    rng = np.random.default_rng(seed)
    extra = np.zeros(n, dtype=np.int64)
    for row, count in lost:
        extra[row] = count
    k = np.arange(n) + np.cumsum(extra)
    tau = 0.5 + period_s * k
    polls = tau[backlog] + np.cumsum(rng.uniform(0.012, 0.017, size=int(tau[-1] / 0.012) + 10))
    t_stall = tau[stall[0]]
    polls = polls[(polls < t_stall) | (polls > t_stall + stall[1])]
    arrival = np.empty(n)
    last = -np.inf
    p = 0
    for i in range(n):
        while polls[p] < tau[i]:
            p += 1
        last = max(polls[p], last + TRANSFER_S)
        arrival[i] = last
    arrival += rng.uniform(0.0, 0.0003, size=n)
    return tau, np.maximum.accumulate(arrival), k - k[0], extra
