"""MAVLink 1/2 framing: a byte stream split into frames whose CRC is good, and the header fields the
server needs before decoding (message id, signed flag).
"""

from __future__ import annotations

import logging

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

logger = logging.getLogger(__name__)


STX_V1 = 0xFE


STX_V2 = 0xFD


V1_HEADER_LEN = 6


V2_HEADER_LEN = 10


CRC_LEN = 2


SIGNATURE_LEN = 13


IFLAG_SIGNED = 0x01


class FrameParser:
    """Splits a byte stream into MAVLink 1/2 frames whose CRC is good.

    A candidate start byte whose frame fails (unknown id, bad CRC, bad flags) costs one byte:
    scanning resumes at the next byte, so a valid frame hidden behind garbage is still found.
    A candidate that stays incomplete for ``partial_timeout_s`` of the caller's clock is
    skipped the same way (``truncated``).
    """

    MAX_BUFFER = 1 << 20

    def __init__(self, stats: dict[str, int], partial_timeout_s: float) -> None:
        self._buf = bytearray()
        self._stats = stats
        self._partial_timeout_s = partial_timeout_s
        self._stall_since_s: float | None = None

    def feed(self, data: bytes) -> None:
        self._buf += data
        excess = len(self._buf) - self.MAX_BUFFER
        if excess > 0:
            del self._buf[:excess]
            self._stats["garbage_bytes"] += excess

    def frames(self, now_s: float) -> list[bytes]:
        out: list[bytes] = []
        while True:
            consumed = self._scan(out)
            if not self._buf:
                self._stall_since_s = None
                return out
            if consumed or self._stall_since_s is None:
                self._stall_since_s = now_s
                return out
            if now_s - self._stall_since_s < self._partial_timeout_s:
                return out
            # a candidate frame never completed: skip its start byte and rescan
            self._stats["truncated"] += 1
            del self._buf[:1]
            self._stall_since_s = now_s

    def _scan(self, out: list[bytes]) -> int:
        buf = self._buf
        n = len(buf)
        i = 0
        stats = self._stats
        while i < n:
            j1 = buf.find(STX_V1, i)
            j2 = buf.find(STX_V2, i)
            if j1 < 0 and j2 < 0:
                stats["garbage_bytes"] += n - i
                i = n
                break
            j = j2 if j1 < 0 else j1 if j2 < 0 else min(j1, j2)
            stats["garbage_bytes"] += j - i
            i = j
            avail = n - i
            if buf[i] == STX_V2:
                if avail < V2_HEADER_LEN:
                    break
                plen, incompat = buf[i + 1], buf[i + 2]
                if incompat & ~IFLAG_SIGNED:
                    stats["parse_errors"] += 1
                    i += 1
                    continue
                hlen = V2_HEADER_LEN
                flen = hlen + plen + CRC_LEN + (SIGNATURE_LEN if incompat & IFLAG_SIGNED else 0)
                msg_id = buf[i + 7] | (buf[i + 8] << 8) | (buf[i + 9] << 16)
            else:
                if avail < V1_HEADER_LEN:
                    break
                plen = buf[i + 1]
                hlen = V1_HEADER_LEN
                flen = hlen + plen + CRC_LEN
                msg_id = buf[i + 5]
            if avail < flen:
                break
            msg_cls = mavlink2.mavlink_map.get(msg_id)
            if msg_cls is None:
                stats["unknown"] += 1
                i += 1
                continue
            crc = mavlink2.x25crc(bytes(buf[i + 1:i + hlen + plen]))
            crc.accumulate(bytes((msg_cls.crc_extra,)))
            wire_crc = buf[i + hlen + plen] | (buf[i + hlen + plen + 1] << 8)
            if crc.crc != wire_crc:
                stats["bad_crc"] += 1
                i += 1
                continue
            out.append(bytes(buf[i:i + flen]))
            i += flen
        del buf[:i]
        return i


def frame_msg_id(frame: bytes) -> int:
    if frame[0] == STX_V2:
        return frame[7] | (frame[8] << 8) | (frame[9] << 16)
    return frame[5]


def frame_is_signed(frame: bytes) -> bool:
    return frame[0] == STX_V2 and bool(frame[2] & IFLAG_SIGNED)
