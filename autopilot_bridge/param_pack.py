"""ArduPilot's packed parameter file ``@PARAM/param.pck`` (what MAVFTP serves QGC, MAVProxy and
Mission Planner instead of a PARAM_REQUEST_LIST stream).

Pure module (struct only). The layout, as ArduPilot's ``AP_Filesystem_Param`` writes it and as
the clients read it (QGC ``ParameterManager::_parseParamFile``, pymavlink
``mavftp.ftp_param_decode``):

* header, little endian: magic u16 (0x671B; 0x671C when defaults are included), the number of
  parameters in the file u16, the total number of parameters u16;
* one record per parameter: a type byte (low nibble 1 int8, 2 int16, 3 int32, 4 float; high
  nibble flags, bit 0 = a default follows the value, only in the 0x671C form), a length byte (high
  nibble = length of the name suffix - 1, low nibble = how many leading characters are shared with
  the previous record's name, at most 15), the name suffix (1..16 bytes, no terminator), the value,
  then the default (same type) if flagged;
* zero bytes between records are padding (a type byte is never 0). ArduPilot pads so that a record
  never straddles one of its read blocks; a whole file generated at once needs none, so there is
  none here.

``withdefaults=1`` includes a default only for parameters whose value differs from it (as
ArduPilot does); ``start`` and ``count`` select a range of parameter indices.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Iterable

from autopilot_bridge.params import ParamType

MAGIC = 0x671B
MAGIC_WITH_DEFAULTS = 0x671C
HEADER = struct.Struct("<HHH")
MAX_COMMON_PREFIX = 15
MAX_SUFFIX_LEN = 16
FLAG_HAS_DEFAULT = 0x10

# MAV_PARAM_TYPE -> (packed type code, struct format): ArduPilot's ap_var_type numbers
PACKED_TYPES: dict[ParamType, tuple[int, str]] = {
    ParamType.INT8: (1, "<b"),
    ParamType.INT16: (2, "<h"),
    ParamType.INT32: (3, "<i"),
    ParamType.REAL32: (4, "<f"),
}


@dataclass(frozen=True)
class PackedParam:
    """One parameter as it goes into the file."""

    name: str
    ptype: ParamType
    value: float
    default: float


@dataclass(frozen=True)
class PackQuery:
    """The query of ``@PARAM/param.pck?withdefaults=1&start=N&count=M``."""

    with_defaults: bool = False
    start: int = 0
    count: int | None = None


def parse_query(query: str) -> PackQuery | None:
    """The options after ``?``; None when a value is not a non-negative integer. Unknown keys are
    ignored (as ArduPilot ignores them)."""
    opts: dict[str, int] = {}
    for part in filter(None, query.split("&")):
        key, _, value = part.partition("=")
        if key in ("withdefaults", "start", "count"):
            if not value.isdigit():
                return None
            opts[key] = int(value)
    return PackQuery(with_defaults=opts.get("withdefaults", 0) == 1, start=opts.get("start", 0),
                     count=opts.get("count"))


def _encode_value(ptype: ParamType, value: float) -> bytes:
    _, fmt = PACKED_TYPES[ptype]
    return struct.pack(fmt, value if ptype == ParamType.REAL32 else int(value))


def pack_params(params: Iterable[PackedParam], query: PackQuery = PackQuery()) -> bytes:
    """The file for ``params`` (in index order) under ``query``."""
    every = list(params)
    end = len(every) if query.count is None else query.start + query.count
    chosen = every[query.start:end]
    out = bytearray(HEADER.pack(MAGIC_WITH_DEFAULTS if query.with_defaults else MAGIC,
                                len(chosen), len(every)))
    previous = b""
    for p in chosen:
        name = p.name.encode("ascii")
        if len(name) > MAX_SUFFIX_LEN:
            raise ValueError(f"parameter name {p.name!r}: longer than 16 characters")
        common = 0
        limit = min(len(previous), len(name) - 1, MAX_COMMON_PREFIX)
        while common < limit and previous[common] == name[common]:
            common += 1
        suffix = name[common:]
        if not 1 <= len(suffix) <= MAX_SUFFIX_LEN:
            raise ValueError(f"parameter name {p.name!r} cannot be packed")
        code, _ = PACKED_TYPES[p.ptype]
        value = _encode_value(p.ptype, p.value)
        has_default = query.with_defaults and _encode_value(p.ptype, p.default) != value
        out.append(code | (FLAG_HAS_DEFAULT if has_default else 0))
        out.append(((len(suffix) - 1) << 4) | common)
        out += suffix + value
        if has_default:
            out += _encode_value(p.ptype, p.default)
        previous = name
    return bytes(out)
