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
* SETUP_SIGNING (what MAVProxy's ``signing setup`` and QGC send) installs a new key on every link
  at once, as ArduPilot's ``GCS_MAVLINK::handle_setup_signing``: refused while armed (WARNING
  "ERROR: Won't setup signing when armed"); an all-zero key disables signing; the outgoing
  timestamp becomes at least the message's ``initial_timestamp``. With a key file
  (``MavlinkServerConfig.signing_key_path``; the node keeps it next to the parameter store, as
  ArduPilot keeps the key in its storage) the key is written there and loaded at the next start,
  over the configuration's. While signing is on, SETUP_SIGNING itself must be signed (it is not
  on the unsigned list), so only a holder of the current key can change it.

The signature check itself (SHA-256 of key + frame, 6 bytes, per-stream timestamps that may
not go backwards and new streams at most one minute behind) is pymavlink's
``MAVLink.check_signature``, run by ``MAVLink.decode``.
"""

from __future__ import annotations

import hashlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from scenenav.core.config import check
from scenenav.core.errors import UserError

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
    """Applies one signing key to the per-link pymavlink ``MAVLink`` objects."""

    def __init__(self, cfg: SigningConfig, wallclock_s: Callable[[], float] = time.time,
                 key_path: str = "") -> None:
        self._key = signing_key(cfg) if cfg.enabled else None
        self._key_path = Path(key_path) if key_path else None
        self._min_timestamp = 0
        self._wallclock_s = wallclock_s
        if self._key_path is not None and self._key_path.exists():
            stored, self._min_timestamp = load_key_file(self._key_path)
            self._key = None if stored == bytes(SIGNING_KEY_LEN) else stored

    @property
    def enabled(self) -> bool:
        return self._key is not None

    def configure(self, mav: mavlink2.MAVLink, link_id: int) -> None:
        """Apply the current key (or no signing) to a link's MAVLink object."""
        mav.signing.link_id = link_id & 0xFF
        if self._key is None:
            mav.signing.secret_key = None
            mav.signing.sign_outgoing = False
            mav.signing.allow_unsigned_callback = None
            return
        mav.signing.secret_key = self._key
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = max(mav.signing.timestamp, self._min_timestamp,
                                    signing_timestamp(self._wallclock_s()))
        mav.signing.allow_unsigned_callback = _accept_unsigned

    def install(self, key: bytes, initial_timestamp: int) -> None:
        """SETUP_SIGNING: the new key (all zeros = signing off), persisted when there is a key
        file; call ``configure`` on every link afterwards."""
        if len(key) != SIGNING_KEY_LEN:
            raise ValueError(f"signing key must be {SIGNING_KEY_LEN} bytes")
        self._key = None if key == bytes(SIGNING_KEY_LEN) else bytes(key)
        self._min_timestamp = max(self._min_timestamp, int(initial_timestamp))
        if self._key_path is not None:
            save_key_file(self._key_path, bytes(key), self._min_timestamp)

    def refresh_timestamp(self, mav: mavlink2.MAVLink) -> None:
        """Keep the outgoing timestamp at least at wall-clock time (it only moves forward)."""
        if self.enabled:
            mav.signing.timestamp = max(mav.signing.timestamp,
                                        signing_timestamp(self._wallclock_s()))

    @staticmethod
    def accepts_unsigned(msg_id: int) -> bool:
        return msg_id in UNSIGNED_ACCEPTED_MSG_IDS


def key_path_beside(params_store: str | Path) -> Path:
    """Where the node keeps the SETUP_SIGNING key for a parameter store (its sibling, like
    ArduPilot's key in the same storage as its parameters): ``<store>.signing.json``."""
    p = Path(params_store)
    return p.with_name(p.name + ".signing.json")


def load_key_file(path: Path) -> tuple[bytes, int]:
    """A key file -> (key, timestamp); a malformed one is a UserError naming it."""
    try:
        data = json.loads(path.read_text())
        key = bytes.fromhex(str(data["secret_key_hex"]))
        stamp = int(data.get("timestamp", 0))
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise UserError(f"signing key file {path}: unreadable ({exc}); expected JSON "
                        f'{{"secret_key_hex": "<64 hex>", "timestamp": N}}') from None
    if len(key) != SIGNING_KEY_LEN:
        raise UserError(f"signing key file {path}: the key must be 64 hex characters")
    return key, stamp


def save_key_file(path: Path, key: bytes, timestamp: int) -> None:
    """Write the key file atomically, readable by its owner only."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(path.suffix + ".tmp")
    tmp.write_text(json.dumps({"secret_key_hex": key.hex(), "timestamp": int(timestamp)}))
    os.chmod(tmp, 0o600)
    os.replace(tmp, path)


def _accept_unsigned(_mav: mavlink2.MAVLink, msg_id: int) -> bool:
    return msg_id in UNSIGNED_ACCEPTED_MSG_IDS
