"""What a live session counts (docs/live.md): the loop's counters, the readers' and the
publisher's copied in, and the latency of each published estimate."""

from __future__ import annotations

import logging
from collections import deque
from dataclasses import dataclass, field

import numpy as np

log = logging.getLogger(__name__)


class LatencyHistogram:
    """Latencies of a whole run in fixed memory: counts in ``bin_ms`` bins up to ``max_ms``
    (longer ones in the last bin), so percentiles of an hour-long run need no sample list."""

    def __init__(self, bin_ms: float = 0.1, max_ms: float = 2000.0):
        self.bin_ms = bin_ms
        self.counts = np.zeros(int(round(max_ms / bin_ms)) + 1, np.int64)

    def add(self, ms: float) -> None:
        self.counts[min(int(ms / self.bin_ms), len(self.counts) - 1)] += 1

    @property
    def n(self) -> int:
        return int(self.counts.sum())

    def percentile(self, q: float) -> float:
        """The q-th percentile in ms (upper edge of its bin: never under the true value by more
        than nothing, never over by more than one bin); NaN when empty."""
        n = self.n
        if n == 0:
            return float("nan")
        k = int(np.searchsorted(np.cumsum(self.counts), max(1, int(np.ceil(q / 100.0 * n)))))
        return (k + 1) * self.bin_ms


@dataclass
class LiveStats:
    """What a live session counted; each event is counted once, in one counter.

    The serial reader's, camera's and publisher's own counters are copied in by
    ``LiveSession.update_stats`` (the status line and the final summary show them all)."""
    samples: int = 0              # eye samples the loop processed
    published: int = 0            # messages published
    no_pose: int = 0              # samples with a valid eye but no head pose at their time
    shed: int = 0                 # samples too late to estimate when the loop took them (loop.SHED_AFTER_S)
    targets: int = 0              # target messages (a target seen again is published again)
    distinct_targets: int = 0     # distinct target ids
    frames_skipped: int = 0       # frames tracking did not see: passed over for a newer one, or the
    #                               camera queue had no room (every one still recorded)
    frames: int = 0               # frames captured
    frames_missed: int = 0        # frames a camera device did not deliver (short gaps)
    camera_stalls: int = 0        # waits of over 5 frame periods
    eye_records: int = 0          # intact records received
    corrupt: int = 0              # records that failed their checksum or format
    lost: int = 0                 # records missing by the counter, never received at all
    reader_dropped: int = 0       # intact records the loop had no room for (still recorded)
    publish_dropped: int = 0      # messages a subscriber did not get (its queue was full, or it was disconnected)
    reconnects: int = 0
    end_reason: str = ""
    latencies_ms: deque = field(default_factory=lambda: deque(maxlen=5000))   # the recent ones, for the status line
    latency_all: LatencyHistogram = field(default_factory=LatencyHistogram)   # the whole run
    sample_cpu: LatencyHistogram = field(default_factory=LatencyHistogram)    # CPU time of each published
    #                               estimate's sample in the loop's thread (pose, estimate, publish), ms
    taken: LatencyHistogram = field(default_factory=LatencyHistogram)         # each sample's time (a device's
    #                               sample time, the serial reader's arrival) to the loop taking it, ms

    def add_latency(self, ms: float) -> None:
        """One published estimate's latency, ms (arrival of its sample to its message)."""
        self.latencies_ms.append(ms)
        self.latency_all.add(ms)

    def counters(self) -> str:
        """Every counter, one line."""
        return (f"frames {self.frames} (skipped {self.frames_skipped}, missed {self.frames_missed}, stalls "
                f"{self.camera_stalls})  eye {self.eye_records} (corrupt {self.corrupt}, lost {self.lost}, dropped "
                f"{self.reader_dropped}, reconnects {self.reconnects}, no pose {self.no_pose}, shed {self.shed})  "
                f"messages {self.published} (dropped {self.publish_dropped})")
