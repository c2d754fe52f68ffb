"""The server's resident memory, threads and open file descriptors over time, read from
/proc (Linux): VmRSS and Threads of /proc/PID/status, the entries of /proc/PID/fd. A
leak shows as one of them climbing while the load stays the same, or not coming back
down once it stops."""

from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass
from typing import List, Optional


@dataclass
class Sample:
    t: float  # seconds since the sampler started
    phase: str
    rss_mb: float
    threads: int
    fds: int


def sample(pid: int, t: float = 0.0, phase: str = "") -> Optional[Sample]:
    """One reading, or None when the process is gone."""
    try:
        status = open(f"/proc/{pid}/status").read()
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = dict(line.split(":", 1) for line in status.splitlines() if ":" in line)
    return Sample(t, phase, int(fields["VmRSS"].split()[0]) / 1024, int(fields["Threads"]), fds)


class Sampler(threading.Thread):
    """Reads the process every `interval` seconds, labelling each reading with the phase
    set last (`sampler.phase = "2x"`)."""

    def __init__(self, pid: int, interval: float) -> None:
        super().__init__(daemon=True)
        self.pid, self.interval, self.phase = pid, interval, "start"
        self.samples: List[Sample] = []
        self._stop_event = threading.Event()
        self._t0 = time.monotonic()

    def run(self) -> None:
        while not self._stop_event.is_set():
            s = sample(self.pid, time.monotonic() - self._t0, self.phase)
            if s is None:
                return
            self.samples.append(s)
            self._stop_event.wait(self.interval)

    def now(self) -> Optional[Sample]:
        return sample(self.pid, time.monotonic() - self._t0, self.phase)

    def stop(self) -> None:
        self._stop_event.set()
        self.join()

    def of(self, phase: str) -> List[Sample]:
        return [s for s in self.samples if s.phase == phase]
