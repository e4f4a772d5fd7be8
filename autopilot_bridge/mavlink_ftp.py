"""MAVLink FTP (FILE_TRANSFER_PROTOCOL) the way ArduPilot answers it, over a read-only set of
virtual files: today only ``@PARAM/param.pck`` (``param_pack``), generated when it is opened.

Pure module (struct only): :meth:`FtpServer.handle` takes the 251-byte payload of a request and
returns the payloads of the replies; the MAVLink server wraps them in FILE_TRANSFER_PROTOCOL
messages. Behaviour follows ArduPilot's ``GCS_FTP.cpp`` (``libraries/GCS_MAVLink``):

* header ``<HBBBBBBI``: seq, session, opcode, size, req_opcode, burst_complete, padding, offset;
  then 239 data bytes. A reply carries ``seq + 1``, the request's session and opcode in
  ``req_opcode``; a NAK has ``size`` 1 (2 for FailErrno: + errno) and the error code in data[0];
* a request whose ``seq + 1`` is the last reply's (the client resends after a lost reply) gets that
  reply again, unchanged;
* ResetSessions closes the sessions of that client and is always ACKed; TerminateSession closes
  one; None is ACKed; ACK/NAK from a client are eaten;
* OpenFileRO of a path that does not exist -> NAK FileNotFound (ArduPilot's ENOENT translation),
  which QGC, MAVProxy and Mission Planner take as "no such file" and fall back to
  PARAM_REQUEST_LIST at once; a second open on a session with an open file -> NAK Fail (unless
  the session was idle for 3 s, ArduPilot's ``FTP_SESSION_TIMEOUT``);
* ReadFile / BurstReadFile / WriteFile without an open file -> NAK FileNotFound; at the end of
  the file -> NAK EndOfFile (burst: with burst_complete); a burst sends the rest of the file;
* ListDirectory, CalcFileCRC32, RemoveFile, RemoveDirectory and Rename of a path that does not
  exist -> FileNotFound; there are no directories to list (ArduPilot lists its SD card and the
  ``@PARAM``, ``@SYS``, ``@ROMFS`` virtual folders);
* nothing is writable: CreateFile, OpenFileWO, CreateDirectory, and removing or renaming a
  virtual file -> NAK FailErrno with EROFS (ArduPilot would write to its SD card);
* TruncateFile and unknown opcodes -> NAK UnknownCommand;
* a name whose length does not match ``size`` -> NAK InvalidDataSize; ``size`` > 239 likewise.
"""

from __future__ import annotations

import errno
import struct
from dataclasses import dataclass, field
from enum import IntEnum
from typing import Callable, Hashable

HEADER = struct.Struct("<HBBBBBBI")
PAYLOAD_LEN = 251
DATA_LEN = PAYLOAD_LEN - HEADER.size          # 239
SESSION_TIMEOUT_S = 3.0                        # GCS_FTP.cpp FTP_SESSION_TIMEOUT (3000 ms)
BURST_MAX_PACKETS = 2000                       # GCS_FTP.cpp transfer_size of one burst


class FtpOp(IntEnum):
    """Opcodes (MAVLink FTP specification, ArduPilot ``GCS_FTP::FTP_OP``)."""

    NONE = 0
    TERMINATE_SESSION = 1
    RESET_SESSIONS = 2
    LIST_DIRECTORY = 3
    OPEN_FILE_RO = 4
    READ_FILE = 5
    CREATE_FILE = 6
    WRITE_FILE = 7
    REMOVE_FILE = 8
    CREATE_DIRECTORY = 9
    REMOVE_DIRECTORY = 10
    OPEN_FILE_WO = 11
    TRUNCATE_FILE = 12
    RENAME = 13
    CALC_FILE_CRC32 = 14
    BURST_READ_FILE = 15
    ACK = 128
    NAK = 129


class FtpError(IntEnum):
    """NAK codes (MAVLink FTP specification)."""

    NONE = 0
    FAIL = 1
    FAIL_ERRNO = 2
    INVALID_DATA_SIZE = 3
    INVALID_SESSION = 4
    NO_SESSIONS_AVAILABLE = 5
    END_OF_FILE = 6
    UNKNOWN_COMMAND = 7
    FILE_EXISTS = 8
    FILE_PROTECTED = 9
    FILE_NOT_FOUND = 10


@dataclass
class FtpPacket:
    seq: int
    session: int
    opcode: int
    size: int
    req_opcode: int
    burst_complete: int
    offset: int
    data: bytes = b""

    @classmethod
    def decode(cls, payload: bytes) -> FtpPacket | None:
        if len(payload) < HEADER.size:
            return None
        seq, session, opcode, size, req, burst, _pad, offset = HEADER.unpack_from(payload)
        return cls(seq, session, opcode, size, req, burst, offset,
                   bytes(payload[HEADER.size:PAYLOAD_LEN]).ljust(DATA_LEN, b"\0"))

    def encode(self) -> bytes:
        head = HEADER.pack(self.seq & 0xFFFF, self.session, self.opcode, self.size,
                           self.req_opcode, self.burst_complete, 0, self.offset & 0xFFFFFFFF)
        return head + self.data[:DATA_LEN].ljust(DATA_LEN, b"\0")


# A file resolver: path (query included) -> contents, or None when there is no such file.
FileResolver = Callable[[str], "bytes | None"]


@dataclass
class _Session:
    content: bytes | None = None    # the open file (read-only), None = nothing open
    last_activity_s: float = 0.0


@dataclass
class _Client:
    sessions: dict[int, _Session] = field(default_factory=dict)
    last_reply: FtpPacket | None = None


class FtpServer:
    """FTP state of every client (key = link and MAVLink system/component)."""

    def __init__(self, resolve: FileResolver) -> None:
        self._resolve = resolve
        self._clients: dict[Hashable, _Client] = {}

    def forget(self, is_gone: Callable[[Hashable], bool]) -> None:
        """Drop the sessions of the clients for which ``is_gone(key)`` (their link closed)."""
        for key in [k for k in self._clients if is_gone(k)]:
            del self._clients[key]

    def handle(self, client: Hashable, payload: bytes, now_s: float) -> list[bytes]:
        """Reply payloads for one request payload (none for a malformed one, an ACK or a NAK)."""
        req = FtpPacket.decode(payload)
        if req is None or req.opcode in (FtpOp.ACK, FtpOp.NAK):
            return []
        state = self._clients.setdefault(client, _Client())
        last = state.last_reply
        if req.opcode == FtpOp.RESET_SESSIONS:
            state.sessions.clear()
            replies = [self._reply(req, FtpOp.ACK)]
        elif (last is not None and req.session == last.session
                and (req.seq + 1) & 0xFFFF == last.seq):
            return [last.encode()]                         # a resend: the same answer
        else:
            replies = self._dispatch(state, req, now_s)
        state.last_reply = replies[-1]
        return [r.encode() for r in replies]

    # ----------------------------------------------------------------- requests
    def _dispatch(self, state: _Client, req: FtpPacket, now_s: float) -> list[FtpPacket]:
        if req.size > DATA_LEN:
            return [self._nak(req, FtpError.INVALID_DATA_SIZE)]
        session = state.sessions.setdefault(req.session, _Session())
        op = req.opcode
        if op == FtpOp.NONE:
            return [self._reply(req, FtpOp.ACK)]
        if op == FtpOp.TERMINATE_SESSION:
            state.sessions.pop(req.session, None)
            return [self._reply(req, FtpOp.ACK)]
        if op == FtpOp.OPEN_FILE_RO:
            return [self._open(session, req, now_s)]
        if op == FtpOp.READ_FILE:
            return [self._read(session, req, now_s)]
        if op == FtpOp.BURST_READ_FILE:
            return self._burst(session, req, now_s)
        if op == FtpOp.WRITE_FILE:
            return [self._nak(req, FtpError.FILE_NOT_FOUND)]     # never open for writing
        if op in (FtpOp.CREATE_FILE, FtpOp.OPEN_FILE_WO, FtpOp.CREATE_DIRECTORY):
            if _path(req) is None:
                return [self._nak(req, FtpError.INVALID_DATA_SIZE)]
            return [self._nak(req, FtpError.FAIL_ERRNO, errno.EROFS)]
        if op in (FtpOp.LIST_DIRECTORY, FtpOp.CALC_FILE_CRC32, FtpOp.REMOVE_FILE,
                  FtpOp.REMOVE_DIRECTORY, FtpOp.RENAME):
            return [self._on_path(req)]
        return [self._nak(req, FtpError.UNKNOWN_COMMAND)]

    def _open(self, session: _Session, req: FtpPacket, now_s: float) -> FtpPacket:
        if session.content is not None and now_s - session.last_activity_s <= SESSION_TIMEOUT_S:
            return self._nak(req, FtpError.FAIL)
        session.content = None
        path = _path(req)
        if path is None:
            return self._nak(req, FtpError.INVALID_DATA_SIZE)
        content = self._resolve(path)
        if content is None:
            return self._nak(req, FtpError.FILE_NOT_FOUND)
        session.content = content
        session.last_activity_s = now_s
        return self._reply(req, FtpOp.ACK, struct.pack("<I", len(content)))

    def _read(self, session: _Session, req: FtpPacket, now_s: float) -> FtpPacket:
        content = session.content
        if content is None:
            return self._nak(req, FtpError.FILE_NOT_FOUND)
        session.last_activity_s = now_s
        chunk = content[req.offset:req.offset + min(DATA_LEN, req.size)]
        if not chunk:
            return self._nak(req, FtpError.END_OF_FILE, offset=req.offset)
        return self._reply(req, FtpOp.ACK, chunk, offset=req.offset)

    def _burst(self, session: _Session, req: FtpPacket, now_s: float) -> list[FtpPacket]:
        content = session.content
        if content is None:
            return [self._nak(req, FtpError.FILE_NOT_FOUND)]
        session.last_activity_s = now_s
        step = req.size if req.size > 0 else DATA_LEN
        out: list[FtpPacket] = []
        offset = req.offset
        for i in range(BURST_MAX_PACKETS):
            chunk = content[offset:offset + step]
            if not chunk:
                nak = self._nak(req, FtpError.END_OF_FILE, offset=offset)
                nak.seq = (req.seq + 1 + i) & 0xFFFF
                nak.burst_complete = 1
                out.append(nak)
                break
            pkt = self._reply(req, FtpOp.ACK, chunk, offset=offset)
            pkt.seq = (req.seq + 1 + i) & 0xFFFF
            pkt.burst_complete = int(i == BURST_MAX_PACKETS - 1)
            out.append(pkt)
            offset += len(chunk)
        return out

    def _on_path(self, req: FtpPacket) -> FtpPacket:
        if req.opcode == FtpOp.RENAME:
            names = req.data[:req.size].split(b"\0")
            if len(names) < 2 or not names[0] or not names[1]:
                return self._nak(req, FtpError.INVALID_DATA_SIZE)
            path: str | None = names[0].decode("ascii", errors="replace")
        else:
            path = _path(req)
        if path is None:
            return self._nak(req, FtpError.INVALID_DATA_SIZE)
        if req.opcode == FtpOp.LIST_DIRECTORY or self._resolve(path) is None:
            return self._nak(req, FtpError.FILE_NOT_FOUND, offset=req.offset)
        if req.opcode == FtpOp.CALC_FILE_CRC32:
            return self._nak(req, FtpError.FAIL)          # not computed for virtual files
        return self._nak(req, FtpError.FAIL_ERRNO, errno.EROFS)

    # ----------------------------------------------------------------- replies
    @staticmethod
    def _reply(req: FtpPacket, opcode: FtpOp, data: bytes = b"", offset: int = 0) -> FtpPacket:
        return FtpPacket((req.seq + 1) & 0xFFFF, req.session, int(opcode), len(data),
                         req.opcode, 0, offset, data)

    def _nak(self, req: FtpPacket, error: FtpError, errno_value: int | None = None,
             offset: int = 0) -> FtpPacket:
        data = bytes((int(error),)) if errno_value is None else bytes((int(error), errno_value))
        return self._reply(req, FtpOp.NAK, data, offset)


def _path(req: FtpPacket) -> str | None:
    """The request's path, None when ``size`` does not match it (``check_name_len``)."""
    name_len = req.data.find(b"\0")
    if name_len < 0:
        name_len = DATA_LEN
    if req.size == 0:
        return None
    if not (name_len == req.size or (req.size - name_len == 1)):
        return None
    return req.data[:name_len].decode("ascii", errors="replace")
