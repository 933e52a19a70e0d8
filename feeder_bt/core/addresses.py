"""Addresses typed by a person (``[HOST:]PORT``), read one way for every listener and
client of the plant floor."""

from __future__ import annotations

from feeder_bt.core.errors import FeederError


def parse_hostport(text: str, default_port: int, what: str) -> tuple[str, int]:
    """``[HOST:]PORT`` (``PORT`` alone: loopback) to (host, port); one-line error."""
    text = text.strip()
    host, sep, port_text = text.rpartition(":")
    if not sep:
        host, port_text = "127.0.0.1", text
    host = host.strip("[]") or "127.0.0.1"
    try:
        port = int(port_text) if port_text else default_port
    except ValueError:
        raise FeederError(f"{what}: expected [HOST:]PORT, got {text!r}") from None
    if not 0 <= port <= 65535:
        raise FeederError(f"{what}: port must be 0..65535, got {port}")
    return host, port
