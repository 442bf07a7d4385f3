"""The worked example of docs/protocol.md (section 10): its byte dumps, for the Python and the C codec's tests."""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

DOC = Path(__file__).resolve().parents[1] / "docs" / "protocol.md"


@dataclass(frozen=True)
class DocumentedFrame:
    """One frame of the worked example.

    Attributes
    ----------
    name : str
        The frame type's name (``FrameType`` member).
    sender : str
        ``"client"`` or ``"target"``.
    seq : int
        The sequence number the dump's title states.
    size : int
        The size the dump's title states, bytes.
    data : bytes
        The dumped bytes.
    """

    name: str
    sender: str
    seq: int
    size: int
    data: bytes


def documented_frames() -> list[DocumentedFrame]:
    """Every frame dump of docs/protocol.md, in order."""
    dumps = re.findall(r"```text\n(\w+) \((client|target), seq (\d+)\), (\d+) bytes\n((?:[0-9a-f]{4} .*\n)+)```",
                       DOC.read_text())
    return [DocumentedFrame(name, sender, int(seq), int(size),
                            bytes.fromhex("".join(line[6:] for line in hexdump.splitlines())))
            for name, sender, seq, size, hexdump in dumps]
