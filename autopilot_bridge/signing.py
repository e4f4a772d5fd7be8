"""MAVLink 2 message signing for the autopilot emulator (shell module: uses pymavlink).

The 32-byte secret key comes from the configuration, either as 64 hex characters
(``key_hex``) or as a passphrase hashed with SHA-256 (``passphrase``; the same derivation as
MAVProxy's ``signing setup PASSPHRASE``). When signing is enabled:

* every outgoing frame is signed (link id = the server's link number, timestamp in 10 us
  units since 2015-01-01 UTC, never going backwards);
* incoming frames must carry a valid signature. Unsigned frames are refused except
  RADIO_STATUS and RADIO, the two ids ArduPilot accepts unsigned
  (``libraries/GCS_MAVLink/GCS_Signing.cpp``, ``accept_unsigned_callback``); ArduPilot also
  accepts everything on its USB channel 0, which has no equivalent here;
* SETUP_SIGNING from the network is refused: the key comes from the configuration only.

The signature check itself (SHA-256 of key + frame, 6 bytes, per-stream timestamps that may
not go backwards and new streams at most one minute behind) is pymavlink's
``MAVLink.check_signature``, run by ``MAVLink.decode``.
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from scenenav.core.config import check

SIGNING_KEY_LEN = 32
# 2015-01-01T00:00:00Z as a Unix time: the MAVLink signing epoch.
SIGNING_EPOCH_UNIX_S = 1_420_070_400
SIGNING_TICKS_PER_S = 100_000  # 10 microsecond units

# ArduPilot's unsigned accept list (GCS_Signing.cpp).
UNSIGNED_ACCEPTED_MSG_IDS: frozenset[int] = frozenset({
    mavlink2.MAVLINK_MSG_ID_RADIO_STATUS,
    mavlink2.MAVLINK_MSG_ID_RADIO,
})


@dataclass(frozen=True)
class SigningConfig:
    """``enabled`` with exactly one of ``key_hex`` (64 hex chars) or ``passphrase``."""

    enabled: bool = False
    key_hex: str = ""
    passphrase: str = ""

    def __post_init__(self) -> None:
        if not self.enabled:
            return
        check(bool(self.key_hex) != bool(self.passphrase), "signing", "key_hex/passphrase",
              "exactly one of signing.key_hex or signing.passphrase when signing.enabled")
        if self.key_hex:
            ok = len(self.key_hex) == 2 * SIGNING_KEY_LEN
            try:
                bytes.fromhex(self.key_hex)
            except ValueError:
                ok = False
            check(ok, "signing.key_hex", "<hidden>", "64 hexadecimal characters (32 bytes)")


def signing_key(cfg: SigningConfig) -> bytes:
    """The 32-byte secret key of a config (hex key, or SHA-256 of the passphrase)."""
    if cfg.key_hex:
        return bytes.fromhex(cfg.key_hex)
    return hashlib.sha256(cfg.passphrase.encode("utf-8")).digest()


def signing_timestamp(unix_time_s: float) -> int:
    """A MAVLink signing timestamp (10 us ticks since 2015-01-01) for a Unix time."""
    return max(0, int((unix_time_s - SIGNING_EPOCH_UNIX_S) * SIGNING_TICKS_PER_S))


class Signer:
    """Applies one signing configuration to the per-link pymavlink ``MAVLink`` objects."""

    def __init__(self, cfg: SigningConfig, wallclock_s: Callable[[], float] = time.time) -> None:
        self.enabled = cfg.enabled
        self._key = signing_key(cfg) if cfg.enabled else None
        self._wallclock_s = wallclock_s

    def configure(self, mav: mavlink2.MAVLink, link_id: int) -> None:
        """Enable signing (outgoing and incoming checks) on a link's MAVLink object."""
        if not self.enabled:
            return
        mav.signing.secret_key = self._key
        mav.signing.sign_outgoing = True
        mav.signing.link_id = link_id & 0xFF
        mav.signing.timestamp = signing_timestamp(self._wallclock_s())
        mav.signing.allow_unsigned_callback = _accept_unsigned

    def refresh_timestamp(self, mav: mavlink2.MAVLink) -> None:
        """Keep the outgoing timestamp at least at wall-clock time (it only moves forward)."""
        if self.enabled:
            mav.signing.timestamp = max(mav.signing.timestamp,
                                        signing_timestamp(self._wallclock_s()))

    @staticmethod
    def accepts_unsigned(msg_id: int) -> bool:
        return msg_id in UNSIGNED_ACCEPTED_MSG_IDS


def _accept_unsigned(_mav: mavlink2.MAVLink, msg_id: int) -> bool:
    return msg_id in UNSIGNED_ACCEPTED_MSG_IDS
