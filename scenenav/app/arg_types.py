"""argparse value types shared by the ``scenenav`` subcommands: each turns bad text into argparse's
one-line usage error (exit 2), never a traceback."""

from __future__ import annotations

import argparse


def positive_int(text: str) -> int:
    """An integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive integer") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive integer")
    return value


def nonneg_int(text: str) -> int:
    """An integer >= 0."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected an integer >= 0") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"{text!r}: expected an integer >= 0")
    return value


def positive_float(text: str) -> float:
    """A finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive number") from None
    if not (value > 0.0 and value != float("inf")):
        raise argparse.ArgumentTypeError(f"{text!r}: expected a positive number")
    return value


MAX_PORT = 65535


def port_number(text: str) -> int:
    """A TCP port, 0 to 65535 (0: any free port)."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a port number 0 to {MAX_PORT}") from None
    if not 0 <= value <= MAX_PORT:
        raise argparse.ArgumentTypeError(f"{text!r}: expected a port number 0 to {MAX_PORT}")
    return value


def ipv4_address(text: str) -> str:
    """A dotted IPv4 address (127.0.0.1, 0.0.0.0, 192.168.1.20)."""
    import ipaddress
    try:
        return str(ipaddress.IPv4Address(text))
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: expected an IPv4 address such as 127.0.0.1") from None


def add_flight_kind_arguments(parser: argparse.ArgumentParser, realism_default: str,
                              scripted_means: str) -> None:
    """``--realism {ideal,paper,realistic}`` and ``--scripted``, as the Table-2 flights take them
    (``experiment table2``, ``cnn decision-data``); the help texts name each command's default."""
    from scenenav.app.realism import Realism
    parser.add_argument("--realism", choices=[r.value for r in Realism],
                        help=f"realism profile of every flight (docs/realism.md; default: {realism_default})")
    parser.add_argument("--scripted", action="store_true",
                        help=f"fly the kinematic path without the autopilot ({scripted_means}) instead of "
                             f"the autopilot mission table2 flies by default")
