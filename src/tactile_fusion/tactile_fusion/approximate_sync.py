"""Approximate-time synchronisation of camera streams into bundles (one message per camera), without ROS.

Semantics follow the ApproximateTime policy of ROS message_filters (C++): a bundle always contains the *pivot*,
the latest of the queue heads once every queue holds a message, and among the bundles containing it the one with
the smallest time spread is chosen. A bundle is emitted only once no message still to come could form a bundle
with a smaller spread, so the output depends only on the timestamps, not on the arrival order across cameras.
This is our own implementation of those documented semantics (message_filters has no PyPI wheel for ROS 2).

One addition, off by default (`keep_grouping_s` 0): the grouping the bundles follow is kept while it stays nearly
as tight as the tightest. Cameras without a common trigger capture at phases of their own; where two groupings of
those phases are about as tight, the stamps' jitter makes first one and then the other the tightest, and every
switch supersedes a frame of some cameras (of 100 random phase sets of four 40 Hz cameras with 1 ms of jitter,
400 frames each, 21 lost more than 5 % of their frames that way, the worst 23 %). So the bundle of every stream's
oldest queued message goes out as soon as it continues the last bundle's grouping (every stream moved on by about
the same time since then; a stream that lost a frame moved on by a period more), lies within `max_spread_s`, and is
less than `keep_grouping_s` wider than any bundle holding the pivot could be (messages still to come included). A
grouping that drifts wider than that gives way to the tightest, superseding a frame once. The first bundle, and the
first after a reset, is the tightest.

The output depends only on the timestamps as long as each stream keeps to `min_period_s` and no queue overflows
(an overflow, or a restart, depends on what had arrived; so it is with message_filters). With the addition as well:
the lower bound never exceeds the tightest bundle's spread, and the tightest rule emits only once the bound equals
it, so whether the heads go out does not depend on when it is asked.

Knobs, as in message_filters:
- `max_spread_s` (max_interval_duration): a bundle whose best spread exceeds it is not emitted; the oldest head
  is dropped instead (counted in `dropped`).
- `min_period_s` (inter-message lower bound, per stream): the next message of a stream cannot be stamped earlier
  than the last one plus this period, which lets a bundle be emitted without waiting for that message.

Streams must be stamped in increasing order; a message stamped at or before its predecessor is dropped
(`out_of_order`). One stamped more than `restart_jump_s` before its predecessor is not a late message but a stream
that started over: a replayed bag that loops, a clock set back, a camera that restarted. Dropping it, and every
later one until the stamps pass the old ones again, would stall the bundles for as long as the stamps went back
(for ever with a looping bag); instead the synchroniser resets (every queue emptied, counted as `reset`, and every
stream's order forgotten), calls `on_restart`, and goes on from the new stamps. A reset costs the messages queued,
about one per stream when the streams keep pace, so `camera_sync_settings` sets `restart_jump_s` to two frame
periods: a step back that large would cost more frames as out of order. A message of another stream stamped before
the jump and arriving after it causes one more reset.
Time is whatever unit the caller uses consistently (seconds in the nodes).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from typing import Any, Generic, TypeVar

from tactile_description.value_checks import is_number, is_whole_number

Item = TypeVar("Item")


def camera_sync_settings(frame_rate_hz: float) -> dict[str, float | int]:
    """The default settings for cameras at `frame_rate_hz`: one frame period for the spread, half of one for the
    period bound, a quarter of one to keep a grouping, two for a step back that restarts the synchronisation (module
    docstring).

    Why a whole period: cameras without a common trigger (each camera node has its own timer) capture at phases of
    their own, and the tightest set of one frame per camera then spans up to (1 - 1/n) of a period, three quarters for
    four cameras spread evenly. With half a period as the limit only half of the phase sets fit (4 x (1/2)^3); of 100
    random ones, 30 got no bundle at all (only `too_wide` drops) and 46 % of the frames were bundled, against 94 % with
    one period. A set always fits in one period.

    Why a quarter period to keep a grouping (module docstring): of the same kind of 100 phase sets, 400 frames each,
    99.8 % of the frames were bundled against 96.6 % with the tightest bundle alone (1 ms of jitter), 99.2 against
    91.6 % with 3 ms; half a period bundled 0.05 and 0.6 points more, for wider bundles (docs/nodes.md)."""
    period_s = 1.0 / frame_rate_hz
    return {"queue_size": 10, "max_spread_s": period_s, "min_period_s": 0.5 * period_s, "restart_jump_s": 2 * period_s,
            "keep_grouping_s": 0.25 * period_s}


@dataclass
class Bundle(Generic[Item]):
    """One synchronised set: `items[i]` and `stamps[i]` belong to stream `stream_ids[i]`."""

    stream_ids: tuple[str, ...]
    stamps: tuple[float, ...]
    items: tuple[Item, ...]

    @property
    def spread(self) -> float:
        return max(self.stamps) - min(self.stamps)


@dataclass
class SyncCounters:
    """What the synchroniser had to drop, by reason and by stream (bundle_node logs them while they grow).

    - out_of_order: stamped at or before the stream's previous message (within `restart_jump_s` of it);
    - queue_overflow: the oldest of a full queue;
    - too_wide: the oldest head, when the tightest bundle holding the pivot was wider than `max_spread_s`;
    - superseded: older than a stream's message in the bundle emitted, so it cannot be in a later bundle;
    - reset: still queued when the synchroniser reset (a stream's stamps jumped back, or the caller called reset);
    - bad_stamp: never given to the synchroniser, stamped with a time no bundle can carry (`drop_bad_stamp`: a
      negative ROS time for one; counted here by its callers, bundle_node and tactile-bag eval, so that one report
      holds every image dropped).
    """

    out_of_order: int = 0
    queue_overflow: int = 0
    too_wide: int = 0
    superseded: int = 0
    reset: int = 0
    bad_stamp: int = 0
    per_stream: dict[str, int] = field(default_factory=dict)

    def drop_bad_stamp(self, stream_id: str) -> None:
        """Count an image of `stream_id` dropped for its stamp (bad_stamp)."""
        self.bad_stamp += 1
        self.per_stream[stream_id] = self.per_stream.get(stream_id, 0) + 1

    def by_reason(self) -> dict[str, int]:
        return {f.name: getattr(self, f.name) for f in fields(self) if f.name != "per_stream"}

    @property
    def total(self) -> int:
        return sum(self.by_reason().values())

    def snapshot(self) -> SyncCounters:
        return replace(self, per_stream=dict(self.per_stream))

    def since(self, earlier: SyncCounters) -> SyncCounters:
        """The drops counted after `earlier`, a snapshot of these counters."""
        counts = {reason: n - getattr(earlier, reason) for reason, n in self.by_reason().items()}
        return SyncCounters(**counts, per_stream={s: n - earlier.per_stream.get(s, 0)
                                                  for s, n in self.per_stream.items()})

    def __str__(self) -> str:
        """The non-zero counts, e.g. "out_of_order 12, too_wide 3; cam0 5, cam1 10"."""
        reasons = ", ".join(f"{reason} {n}" for reason, n in self.by_reason().items() if n)
        streams = ", ".join(f"{s} {n}" for s, n in self.per_stream.items() if n)
        return f"{reasons or 'none'}; {streams or 'none'}"


class ApproximateTimeSync(Generic[Item]):
    """Feed messages with `add`; it returns the bundles they complete, oldest first."""

    def __init__(self, stream_ids: list[str] | tuple[str, ...], queue_size: int = 10, max_spread_s: float = 0.02,
                 min_period_s: float = 0.0, restart_jump_s: float = 1.0, keep_grouping_s: float = 0.0,
                 dropped: SyncCounters | None = None, on_restart: Callable[[str, float, float], None] | None = None):
        """`dropped`: the counters to count into (new ones if None), so that a caller that replaces the
        synchroniser keeps one count. `on_restart(stream_id, previous_stamp, stamp)` is called when a stream's stamps
        jump back by more than `restart_jump_s` (module docstring; camera_sync_settings gives two frame periods)."""
        if len(stream_ids) < 1 or len(set(stream_ids)) != len(stream_ids):
            raise ValueError(f"stream ids must be unique and at least one, got {list(stream_ids)}")
        if not is_whole_number(queue_size):
            raise ValueError(f"queue_size must be a whole number >= 1, got {queue_size!r}")
        for name, value in (("max_spread_s", max_spread_s), ("restart_jump_s", restart_jump_s)):
            if not (is_number(value) and value > 0):
                raise ValueError(f"{name} must be a finite number > 0, got {value!r}")
        for name, value in (("min_period_s", min_period_s), ("keep_grouping_s", keep_grouping_s)):
            if not (is_number(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        self.stream_ids = tuple(stream_ids)
        self.queue_size = queue_size
        self.max_spread_s = max_spread_s
        self.min_period_s = min_period_s
        self.restart_jump_s = restart_jump_s
        self.keep_grouping_s = keep_grouping_s
        self.on_restart = on_restart
        self._queues: dict[str, deque[tuple[float, Any]]] = {s: deque() for s in self.stream_ids}
        self._last_stamp: dict[str, float] = {}
        self._last_bundle: dict[str, float] | None = None  # stamp of each stream's message in the last bundle
        self.dropped = dropped if dropped is not None else SyncCounters()
        for s in self.stream_ids:
            self.dropped.per_stream.setdefault(s, 0)

    def add(self, stream_id: str, stamp: float, item: Item) -> list[Bundle[Item]]:
        if stream_id not in self._queues:
            raise KeyError(f"unknown stream {stream_id!r}; expected one of {list(self.stream_ids)}")
        last = self._last_stamp.get(stream_id)
        if last is not None and stamp < last - self.restart_jump_s:
            self.reset()
            if self.on_restart is not None:
                self.on_restart(stream_id, last, stamp)
        elif last is not None and stamp <= last:
            self._drop(stream_id, "out_of_order")
            return []
        self._last_stamp[stream_id] = stamp
        queue = self._queues[stream_id]
        queue.append((stamp, item))
        if len(queue) > self.queue_size:
            queue.popleft()
            self._drop(stream_id, "queue_overflow")
        bundles = []
        while (bundle := self._next_bundle()) is not None:
            bundles.append(bundle)
        return bundles

    def reset(self) -> None:
        """Start over: drop every queued message (counted as `reset`) and forget every stream's last stamp."""
        for s, queue in self._queues.items():
            if queue:
                self._drop(s, "reset", len(queue))
                queue.clear()
        self._last_stamp.clear()
        self._last_bundle = None

    def _drop(self, stream_id: str, reason: str, count: int = 1) -> None:
        setattr(self.dropped, reason, getattr(self.dropped, reason) + count)
        self.dropped.per_stream[stream_id] += count

    def _next_bundle(self) -> Bundle[Item] | None:
        while all(self._queues.values()):
            pivot_stream = max(self.stream_ids, key=lambda s: self._queues[s][0][0])
            pivot_stamp = self._queues[pivot_stream][0][0]
            options = self._options_around(pivot_stream, pivot_stamp)
            best, picks, lower_bound = self._tightest_around(options)
            if self._keeps_grouping(pivot_stamp, lower_bound):
                return self._take(dict.fromkeys(self.stream_ids, 0))
            if best == float("inf") or lower_bound < best:
                return None  # a message still to come could give a tighter bundle: wait for it
            if best > self.max_spread_s:
                oldest = min(self.stream_ids, key=lambda s: self._queues[s][0][0])
                self._queues[oldest].popleft()
                self._drop(oldest, "too_wide")
                continue
            if self._could_tie(options, picks, pivot_stamp):
                return None
            picks[pivot_stream] = 0
            return self._take(picks)
        return None

    def _keeps_grouping(self, pivot_stamp: float, lower_bound: float) -> bool:
        """Whether the queue heads continue the last bundle's grouping and may go out now (module docstring).

        They continue it when every stream moved on by about the same time since the last bundle: the spread of those
        advances is below half the smallest. A stream that lost a frame moved on by two frame periods where the others
        moved by one; its head belongs to another grouping, and the tightest rule decides. There is no grouping to
        keep before the first bundle or after a reset, so the first bundle is always the tightest."""
        if not self.keep_grouping_s or self._last_bundle is None:
            return False
        head_spread = pivot_stamp - min(queue[0][0] for queue in self._queues.values())
        if not (head_spread <= self.max_spread_s and head_spread < lower_bound + self.keep_grouping_s):
            return False
        advances = [self._queues[s][0][0] - self._last_bundle[s] for s in self.stream_ids]
        return max(advances) - min(advances) < 0.5 * min(advances)

    def _options_around(self, pivot_stream: str, pivot_stamp: float) -> dict[str, tuple[int, float, int | None, float]]:
        """Per stream but the pivot's: (before index, before distance, after index or None, after distance bound),
        its last message at or before the pivot and its first after it (see _tightest_around)."""
        options = {}
        for s in self.stream_ids:
            if s == pivot_stream:
                continue
            queue = self._queues[s]
            before = max(i for i, (t, _) in enumerate(queue) if t <= pivot_stamp)  # the head qualifies
            after = before + 1 if before + 1 < len(queue) else None
            if after is not None:
                after_distance = queue[after][0] - pivot_stamp
            else:  # not arrived yet: it cannot be stamped before last + min_period (nor before the pivot)
                after_distance = max(0.0, self._last_stamp[s] + self.min_period_s - pivot_stamp)
            options[s] = (before, pivot_stamp - queue[before][0], after, after_distance)
        return options

    @staticmethod
    def _tightest_around(options: dict[str, tuple[int, float, int | None, float]]
                         ) -> tuple[float, dict[str, int], float]:
        """(spread, picks) of the tightest bundle holding the pivot among the messages queued (spread inf while
        none is complete), and a lower bound on the spread of every bundle holding it, messages to come included.

        With the pivot fixed, each other stream contributes either its last message at or before the pivot
        ("before", distance b_i) or its first message after it ("after", distance a_i); anything else is
        dominated. The spread of a choice is max(b over "before" picks) + max(a over "after" picks), so trying
        every threshold B on the before-distances covers all undominated bundles.

        Of equally tight bundles (stamps on a grid tie exactly) the one of the largest threshold is taken, the most
        messages before the pivot. The streams picking "after" only shrink as the threshold grows, so a tie still
        missing a message lies below every known one and would lose anyway: which of them has arrived does not
        matter. Taking the first known tie let the arrival order choose (found in review).
        """
        if not options:  # a single stream
            return 0.0, {}, 0.0
        best, best_picks, lower_bound = float("inf"), {}, float("inf")
        for threshold in sorted({opt[1] for opt in options.values()} | {0.0}):
            picks, after_max, known = {}, 0.0, True
            for s, (before, b, after, a) in options.items():
                if b <= threshold:
                    picks[s] = before
                else:
                    picks[s] = after
                    after_max = max(after_max, a)
                    known = known and after is not None
            spread = threshold + after_max
            lower_bound = min(lower_bound, spread)
            if known and spread <= best:
                best, best_picks = spread, picks
        return best, best_picks, lower_bound

    def _could_tie(self, options: dict, picks: dict[str, int], pivot_stamp: float) -> bool:
        """Whether a message still to come could replace a pick at the same spread.

        A stream that gives the bundle its last message so far, stamped before the pivot, may still send one
        stamped between that and the pivot: the bundle with it is no wider (often it is the same bundle's spread),
        and, had it arrived first, the tightest bundle would hold it. Emitting now would let the arrival order
        choose between the two; so the bundle waits for the stream's next message, unless `min_period_s` rules out
        one stamped at or before the pivot (with the nodes' default of half a frame period it nearly always does).
        """
        for s, (before, _, after, _) in options.items():
            last = self._last_stamp[s]
            if picks[s] == before and after is None and last < pivot_stamp and last + self.min_period_s <= pivot_stamp:
                return True
        return False

    def _take(self, picks: dict[str, int]) -> Bundle[Item]:
        stamps, items = [], []
        for s in self.stream_ids:
            queue = self._queues[s]
            for _ in range(picks[s]):  # older than the chosen message: can never be in a tighter later bundle
                queue.popleft()
                self._drop(s, "superseded")
            stamp, item = queue.popleft()
            stamps.append(stamp)
            items.append(item)
        self._last_bundle = dict(zip(self.stream_ids, stamps, strict=True))
        return Bundle(self.stream_ids, tuple(stamps), tuple(items))
