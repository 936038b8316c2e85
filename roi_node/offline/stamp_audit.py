"""Input stamps a replay refuses as implausible: named in its summary and counted in the output bag.

The engine (engine/stamps.py) holds a joint state, command or camera info
stamped more than a minute ahead of its stream's time (or over a second
behind it) until the stream follows; one the stream never follows is refused
as `implausible_stamp` when the next plausible stamp arrives, or at the end.
The frames are then paired without it, so nothing in the output records shows
it. Replay therefore judges the stamps of those streams with the same
StreamClock, in the order it feeds them to the engine, says which messages
were refused (the topic, the stamp, how far from the stream's time), and
writes their count into the output bag's metadata (custom_data
IMPLAUSIBLE_STAMPS_KEY), which `validate` gates as `implausible_stamps`.
Frames are not audited here: a refused frame is a dropped frame, which the
summary and validate's stamp-gap gate already show.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from roi_node.engine.stamps import NS_PER_S, StampVerdict, StreamClock

IMPLAUSIBLE_STAMPS_KEY = "roi_node.implausible_stamps"


@dataclass(frozen=True)
class RefusedStamp:
    where: str  # `<bag>: <topic>`
    stamp_ns: int
    from_stream_ns: int  # stamp minus the stream's last plausible stamp: > 0 ahead of it, < 0 behind

    def line(self) -> str:
        distance_s = abs(self.from_stream_ns) / NS_PER_S
        side = "ahead of" if self.from_stream_ns > 0 else "behind"
        return (
            f"{self.where}: stamp {self.stamp_ns} is {distance_s:.6g} s {side} the stream's own time "
            f"(its last plausible stamp {self.stamp_ns - self.from_stream_ns}) and the stream did not follow it: "
            f"refused as {StampVerdict.IMPLAUSIBLE.value}, the frames were paired without it"
        )


@dataclass
class StampAudit:
    """StreamClock's verdicts per stream (`kind` and `where` together name one, as the engine's do)."""

    _clocks: dict[tuple[str, str], StreamClock] = field(default_factory=dict)
    _held: dict[tuple[str, str], list[RefusedStamp]] = field(default_factory=dict)
    refused: list[RefusedStamp] = field(default_factory=list)

    def see(self, kind: str, where: str, stamp_ns: int) -> None:
        stream = (kind, where)
        clock = self._clocks.setdefault(stream, StreamClock())
        last_ns = clock.last_ns
        check = clock.check(stamp_ns)
        held = self._held.setdefault(stream, [])
        if check.drop_held:
            self.refused.extend(held)
            held.clear()
        if check.verdict is StampVerdict.HELD and last_ns is not None:
            held.append(RefusedStamp(where, stamp_ns, stamp_ns - last_ns))
        elif check.release_held:
            held.clear()

    def finish(self) -> list[RefusedStamp]:
        """Every refused stamp, those still held at the end included (the engine refuses them then too)."""
        for held in self._held.values():
            self.refused.extend(held)
            held.clear()
        return self.refused
