"""Wire protocols: byte streams in, sample chunks out (and, for the simulator, the reverse).

``PARSERS`` and ``ENCODERS`` map a protocol's name to its class, as ``drivers.tables.PROTOCOLS``
does for the rate tables; ``make_parser``/``make_encoder`` build one by name. Delimited text is
the one protocol that needs a ``ChannelMap`` (which column holds what).

The binary protocols (Xsens, VectorNav) load on first use of ``PARSERS``, ``ENCODERS`` or
``make_*``: importing ``drivers.protocols.delimited`` (as a recording import does) runs this file
first, and should not pay for parsers it never uses.
"""
from __future__ import annotations

from drivers.protocols.base import ParserCounters, StreamEncoder, StreamParser
from drivers.protocols.delimited import ChannelMap, DelimitedTextEncoder, DelimitedTextParser

NEEDS_CHANNEL_MAP = frozenset({"delimited"})


_BINARY = ("XsensMtData2Parser", "XsensMtData2Encoder", "VectorNavParser", "VectorNavEncoder")


def __getattr__(name: str):
    """``PARSERS`` and ``ENCODERS`` (and the binary protocols' classes, as before they loaded
    lazily), built and kept as module attributes on first access."""
    if name not in ("PARSERS", "ENCODERS") + _BINARY:
        raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
    if name in globals():  # called directly by make_* after the first build
        return globals()[name]
    from drivers.protocols.vectornav import VectorNavEncoder, VectorNavParser
    from drivers.protocols.xsens import XsensMtData2Encoder, XsensMtData2Parser

    globals().update(
        XsensMtData2Parser=XsensMtData2Parser, XsensMtData2Encoder=XsensMtData2Encoder,
        VectorNavParser=VectorNavParser, VectorNavEncoder=VectorNavEncoder,
        PARSERS={"xsens": XsensMtData2Parser, "vectornav": VectorNavParser, "delimited": DelimitedTextParser},
        ENCODERS={"xsens": XsensMtData2Encoder, "vectornav": VectorNavEncoder, "delimited": DelimitedTextEncoder})
    return globals()[name]


def _build(registry: dict, protocol: str, channel_map: ChannelMap | None):
    try:
        cls = registry[protocol]
    except KeyError:
        raise ValueError(f"imu protocol: expected one of {', '.join(registry)}, got {protocol!r}") from None
    if protocol not in NEEDS_CHANNEL_MAP:
        return cls()
    if channel_map is None:
        raise ValueError(f"imu protocol {protocol!r} needs a channel map (which column holds what)")
    return cls(channel_map)


def make_parser(protocol: str, channel_map: ChannelMap | None = None) -> StreamParser:
    return _build(__getattr__("PARSERS"), protocol, channel_map)


def make_encoder(protocol: str, channel_map: ChannelMap | None = None) -> StreamEncoder:
    return _build(__getattr__("ENCODERS"), protocol, channel_map)


__all__ = [
    "ENCODERS",
    "NEEDS_CHANNEL_MAP",
    "PARSERS",
    "ChannelMap",
    "ParserCounters",
    "StreamEncoder",
    "StreamParser",
    "make_encoder",
    "make_parser",
]
