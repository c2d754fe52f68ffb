"""Retry policy for RESOURCE_EXHAUSTED (the server's estimate queue is full, or the wait
would pass the call's deadline; onboarding slots taken; a rate limit) and UNAVAILABLE:
retries within a time budget, after the wait the server asks for (its ``retry-after-ms``,
from its measured service time) or, without one, exponential backoff with full jitter.

Only the schedule lives here; the sync and async clients each sleep their own way."""

from __future__ import annotations

import logging
import random
from dataclasses import dataclass, field
from typing import FrozenSet, Optional, Union

import grpc

log = logging.getLogger("b2tfpose")

DEFAULT_CODES = frozenset({grpc.StatusCode.RESOURCE_EXHAUSTED, grpc.StatusCode.UNAVAILABLE})


@dataclass(frozen=True)
class RetryPolicy:
    """How failed calls are retried.

    ``budget``: seconds from the first attempt within which retries may start (None: no
    limit but the call's deadline); the default covers many estimates' service times, so a
    burst that fills the server's queue gets through. ``max_attempts`` counts the first
    call (None: as many as the budget allows). When the server says how long to wait
    (``retry-after-ms``), the retry waits that long plus up to ``hint_jitter`` of it more,
    so clients refused together come back spread out. Otherwise the n-th retry waits a
    uniformly random time in [0, min(max_backoff, initial_backoff * multiplier**(n-1))]
    ("full jitter"). A call's own deadline is never extended: no retry starts once it
    would pass, and none when the server's wait would pass it.
    """

    max_attempts: Optional[int] = None
    budget: Optional[float] = 30.0
    initial_backoff: float = 0.1
    max_backoff: float = 5.0
    multiplier: float = 2.0
    hint_jitter: float = 0.25
    codes: FrozenSet[grpc.StatusCode] = field(default_factory=lambda: DEFAULT_CODES)

    def __post_init__(self) -> None:
        if self.max_attempts is not None and self.max_attempts < 1:
            raise ValueError("RetryPolicy.max_attempts must be >= 1 (or None)")
        if self.budget is not None and self.budget < 0:
            raise ValueError("RetryPolicy.budget must be >= 0 seconds (or None)")
        if self.initial_backoff < 0 or self.max_backoff < 0 or self.multiplier < 1 or self.hint_jitter < 0:
            raise ValueError("RetryPolicy: backoffs and hint_jitter must be >= 0 and multiplier >= 1")

    def backoff(self, retry: int, rng: Optional[random.Random] = None, hint: Optional[float] = None) -> float:
        """Seconds to wait before retry number ``retry`` (1-based); ``hint``: the server's
        ``retry-after-ms`` in seconds, when it sent one."""
        r = rng or random
        if hint is not None:
            return hint * (1.0 + r.uniform(0.0, self.hint_jitter))
        cap = min(self.max_backoff, self.initial_backoff * self.multiplier ** (retry - 1))
        return r.uniform(0.0, cap)

    def should_retry(self, code: grpc.StatusCode, attempt: int) -> bool:
        """Whether attempt number ``attempt`` (1-based) that failed with ``code`` is retried
        (the time budget aside)."""
        return code in self.codes and (self.max_attempts is None or attempt < self.max_attempts)


NO_RETRY = RetryPolicy(max_attempts=1)

RetryArg = Union[RetryPolicy, bool, None]


def resolve(per_call: RetryArg, client_policy: RetryPolicy, idempotent: bool) -> RetryPolicy:
    """The policy of one call: ``retry=`` given per call wins (a policy, True for the
    client's, False for none); otherwise idempotent calls use the client's policy and the
    others (onboard, delete, cancel) are not retried."""
    if isinstance(per_call, RetryPolicy):
        return per_call
    if per_call is True:
        return client_policy
    if per_call is False:
        return NO_RETRY
    return client_policy if idempotent else NO_RETRY


def log_retry(method: str, code: grpc.StatusCode, attempt: int, delay: float, hint: Optional[float] = None) -> None:
    asked = "" if hint is None else f" (the server asked for {hint:.3f} s)"
    log.info("b2tfpose: %s failed with %s (attempt %d); retrying in %.3f s%s", method, code.name, attempt, delay, asked)


class Attempts:
    """The attempts of one call under one deadline: what timeout each attempt gets, and
    after a failure either the delay before the next attempt or the exception to raise.
    Both clients drive it, each with its own sleep."""

    def __init__(self, method: str, policy: RetryPolicy, timeout: Optional[float]) -> None:
        import time

        self._clock = time.monotonic
        self.method = method
        self.policy = policy
        start = self._clock()
        self.deadline = None if timeout is None else start + timeout
        self.retry_until = None if policy.budget is None else start + policy.budget
        self.attempt = 0

    def timeout(self) -> Optional[float]:
        """Seconds left for the next attempt (None: no deadline); counts the attempt."""
        self.attempt += 1
        if self.deadline is None:
            return None
        return max(0.0, self.deadline - self._clock())

    def after_failure(self, err: grpc.RpcError) -> float:
        """The delay before retrying ``err``; raises the mapped error when not retried."""
        from .errors import from_grpc

        mapped = from_grpc(err, self.method)
        if self.policy.should_retry(mapped.code, self.attempt):
            delay = self.policy.backoff(self.attempt, hint=mapped.retry_after)
            at = self._clock() + delay
            if all(limit is None or at < limit for limit in (self.deadline, self.retry_until)):
                log_retry(self.method, mapped.code, self.attempt, delay, mapped.retry_after)
                return delay
        raise mapped from None
