"""Two ways of sending the mix: a closed loop (N clients, each sending its next estimate
when the last one is answered: what the server sustains with N slots is its capacity),
and an open loop (requests arrive at a set rate whatever the server does, as independent
clients do: the only honest way to offer more than it can take)."""

from __future__ import annotations

import random
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Callable, List, Sequence, Tuple

from .mix import Mix, Outcome

# The open loop's two streams of arrivals. Requests: estimates are 80 % of them, so that
# "m x capacity" is the estimate rate (the stream's rate is m x capacity / 0.8), bad
# requests, clients giving up and reads the rest. Onboardings: their own stream at m x their own capacity
# (--max-onboardings / one onboarding's time), so that they are overloaded by the same
# factor (a share of the requests would be far more, or far less, than their capacity).
ESTIMATE_SHARE = 0.80
REQUESTS: Sequence[Tuple[str, float]] = (
    ("estimate_http", 0.40),
    ("estimate_grpc", 0.40),
    ("bad_http", 0.06),
    ("bad_grpc", 0.06),
    ("abandon_http", 0.02),
    ("abandon_grpc", 0.02),
    ("read_http", 0.02),
    ("read_grpc", 0.02),
)
ONBOARDINGS: Sequence[Tuple[str, float]] = (("onboard", 1.0),)


def closed_loop(mix: Mix, clients: int, seconds: float) -> List[Outcome]:
    """`clients` threads sending estimates back to back (HTTP and gRPC in turn)."""
    out: List[Outcome] = []
    lock = threading.Lock()
    end = time.monotonic() + seconds

    def client(i: int) -> None:
        n = i
        while time.monotonic() < end:
            res = (mix.estimate_http if n % 2 == 0 else mix.estimate_grpc)()
            n += 1
            with lock:
                out.extend(res)

    threads = [threading.Thread(target=client, args=(i,)) for i in range(clients)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    return out


@dataclass
class OpenLoopRun:
    outcomes: List[Outcome] = field(default_factory=list)
    sent: int = 0
    seconds: float = 0.0
    max_lag_s: float = 0.0  # worst delay between a request's arrival time and its sending
    max_in_flight: int = 0
    unfinished: int = 0  # requests still unanswered when the run gave up waiting


def schedule(streams: Sequence[Tuple[float, Sequence[Tuple[str, float]]]], seconds: float, seed: int) -> List[Tuple[float, str]]:
    """(time, request name) of Poisson arrivals over `seconds`, merged from streams of
    (rate per second, shares of request names)."""
    rng = random.Random(seed)
    out: List[Tuple[float, str]] = []
    for rate, shares in streams:
        names, weights = zip(*shares)
        t = rng.expovariate(rate)
        while t < seconds:
            out.append((t, rng.choices(names, weights)[0]))
            t += rng.expovariate(rate)
    return sorted(out)


def open_loop(mix: Mix, arrivals: List[Tuple[float, str]], seconds: float, workers: int, drain_s: float) -> OpenLoopRun:
    """Sends each request of `arrivals` at its time from a pool of `workers` threads
    (enough that none waits for a thread: `max_lag_s` says whether that held), then
    waits up to `drain_s` for the last answers."""
    run = OpenLoopRun()
    lock = threading.Lock()
    in_flight = [0]
    pending = [0]  # submitted and not yet answered (in flight or waiting for a thread)

    def task(fn: Callable[[], List[Outcome]], due: float) -> None:
        lag = time.monotonic() - due
        with lock:
            in_flight[0] += 1
            run.max_in_flight = max(run.max_in_flight, in_flight[0])
            run.max_lag_s = max(run.max_lag_s, lag)
        try:
            res = fn()
        finally:
            with lock:
                in_flight[0] -= 1
                pending[0] -= 1
        with lock:
            run.outcomes.extend(res)

    pool = ThreadPoolExecutor(max_workers=workers)
    t0 = time.monotonic()
    for at, name in arrivals:
        due = t0 + at
        delay = due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        with lock:
            pending[0] += 1
        pool.submit(task, getattr(mix, name), due)
        run.sent += 1
    time.sleep(max(0.0, t0 + seconds - time.monotonic()))
    run.seconds = time.monotonic() - t0
    pool.shutdown(wait=False)
    end = time.monotonic() + drain_s
    while time.monotonic() < end:
        with lock:
            if pending[0] == 0:
                break
        time.sleep(0.05)
    with lock:
        run.unfinished = pending[0]
    return run
