"""The service's safety rules: where it may listen, the token that guards state changes, what an engine id may be.

Binding: loopback (127.0.0.1, ::1, localhost) by default; any other address only with a token file, so nothing on
the plant network can acknowledge alarms or re-baseline without the token. The token file's content (stripped) is
the token; it must be at least ``MIN_TOKEN_CHARS`` long. Requests carry it as ``Authorization: Bearer <token>``,
compared in constant time (``hmac.compare_digest``). Without a token file on loopback, ``frictionwatch serve`` makes a
random token at start (``new_token``) and prints it once: state changes always need a token.
"""

from __future__ import annotations

import hmac
import ipaddress
import re
from pathlib import Path

ENGINE_ID = re.compile(r"^[a-z0-9-]{1,40}$")
MIN_TOKEN_CHARS = 16
LOOPBACK_NAMES = ("localhost",)


class SecurityError(ValueError):
    """A start-up refusal (one line for the CLI)."""


def is_loopback(host: str) -> bool:
    if host in LOOPBACK_NAMES:
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False  # a host name other than localhost: it may resolve to anything


def check_bind(host: str, token: str | None) -> None:
    """Refuse a non-loopback bind without a token."""
    if not is_loopback(host) and token is None:
        raise SecurityError(f"refusing to listen on {host} without --token-file: state changes (acknowledge, "
                            "baseline) would be open to the network; bind 127.0.0.1 or give a token file")


def read_token(path: Path) -> str:
    """The token in ``path`` (whitespace stripped); refused when missing, empty or short."""
    try:
        token = Path(path).read_text(encoding="utf-8").strip()
    except (OSError, UnicodeDecodeError) as exc:
        raise SecurityError(f"cannot read the token file {path}: {exc}") from exc
    if len(token) < MIN_TOKEN_CHARS or any(c.isspace() for c in token):
        raise SecurityError(f"the token in {path} must be one word of at least {MIN_TOKEN_CHARS} characters")
    return token


def bearer_ok(header: str | None, token: str | None) -> bool:
    """Whether an Authorization header carries ``token``. Without a configured token nothing is authorised
    (``frictionwatch serve`` always has one: from --token-file, or made at start on a loopback bind)."""
    if token is None:
        return False
    if not header or not header.startswith("Bearer "):
        return False
    return hmac.compare_digest(header[len("Bearer "):].strip().encode(), token.encode())


def valid_engine_id(engine_id: str) -> bool:
    return bool(ENGINE_ID.fullmatch(engine_id))


def new_token() -> str:
    import secrets

    return secrets.token_urlsafe(24)
