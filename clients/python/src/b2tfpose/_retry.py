"""Retry policy: exponential backoff with full jitter for RESOURCE_EXHAUSTED (the server
refuses at once when its estimate / onboarding slots are full) and UNAVAILABLE.

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

    ``max_attempts`` counts the first call. The n-th retry waits a uniformly random time in
    [0, min(max_backoff, initial_backoff * multiplier**(n-1))] ("full jitter"), so many
    clients refused together do not come back together. A call's own deadline is never
    extended: no retry starts once it would pass.
    """

    max_attempts: int = 6
    initial_backoff: float = 0.1
    max_backoff: float = 5.0
    multiplier: float = 2.0
    codes: FrozenSet[grpc.StatusCode] = field(default_factory=lambda: DEFAULT_CODES)

    def __post_init__(self) -> None:
        if self.max_attempts < 1:
            raise ValueError("RetryPolicy.max_attempts must be >= 1")
        if self.initial_backoff < 0 or self.max_backoff < 0 or self.multiplier < 1:
            raise ValueError("RetryPolicy: backoffs must be >= 0 and multiplier >= 1")

    def backoff(self, retry: int, rng: Optional[random.Random] = None) -> float:
        """Seconds to wait before retry number ``retry`` (1-based)."""
        cap = min(self.max_backoff, self.initial_backoff * self.multiplier ** (retry - 1))
        return (rng or random).uniform(0.0, cap)

    def should_retry(self, code: grpc.StatusCode, attempt: int) -> bool:
        """Whether attempt number ``attempt`` (1-based) that failed with ``code`` is retried."""
        return code in self.codes and attempt < self.max_attempts


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


def log_retry(method: str, code: grpc.StatusCode, attempt: int, delay: float) -> None:
    log.info("b2tfpose: %s failed with %s (attempt %d); retrying in %.3f s", method, code.name, attempt, delay)


class Attempts:
    """The attempts of one call under one deadline: what timeout each attempt gets, and
    after a failure either the delay before the next attempt or the exception to raise.
    Both clients drive it, each with its own sleep."""

    def __init__(self, method: str, policy: RetryPolicy, timeout: Optional[float]) -> None:
        import time

        self._clock = time.monotonic
        self.method = method
        self.policy = policy
        self.deadline = None if timeout is None else self._clock() + timeout
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
            delay = self.policy.backoff(self.attempt)
            if self.deadline is None or self._clock() + delay < self.deadline:
                log_retry(self.method, mapped.code, self.attempt, delay)
                return delay
        raise mapped from None
