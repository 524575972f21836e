"""What every MIMU wire-protocol parser provides.

A parser is fed whatever bytes arrived, in any split, with the host's monotonic arrival time, and
returns the samples of the frames it completed. It never raises on device bytes: garbage,
truncated frames, bad checksums and counter jumps are skipped, resynchronised and counted.
"""
from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Protocol

from drivers.chunk import SampleChunk


@dataclass
class ParserCounters:
    """What a parser has accepted and thrown away so far (``as_dict`` for reports)."""
    frames: int = 0  # frames accepted
    discarded_bytes: int = 0  # bytes that belonged to no accepted frame
    checksum_failures: int = 0  # frames with the right shape but a wrong checksum
    sequence_gaps: int = 0  # jumps in the device's packet counter
    missing_frames: int = 0  # frames lost in those jumps, where the counter says how many

    def as_dict(self) -> dict[str, int]:
        return asdict(self)


class StreamParser(Protocol):
    counters: ParserCounters
    device_time: bool  # the samples' ``t`` is the device's own clock (else the host's arrival time)

    def feed(self, data: bytes, t_host: float) -> SampleChunk | None:
        """Consume ``data``; return the samples of every frame completed so far, or None."""
        ...


class StreamEncoder(Protocol):
    def encode(self, chunk: SampleChunk) -> bytes:
        """Bytes a real device would send for these samples (used by the simulated devices)."""
        ...
