"""Safety of `frictionwatch serve` (service/security.py): loopback by default, no open bind without a token, the
token compared in constant time, bad command lines refused with one line and exit 2 before anything starts."""

from __future__ import annotations

import hmac

import pytest
from frictionwatch.service import security
from frictionwatch.service.cli import main
from frictionwatch.service.security import SecurityError, bearer_ok, check_bind, read_token


@pytest.mark.parametrize("host", ["127.0.0.1", "127.0.0.53", "::1", "[::1]", "localhost"])
def test_loopback_needs_no_token(host: str) -> None:
    check_bind(host, None)


@pytest.mark.parametrize("host", ["0.0.0.0", "::", "192.168.1.20", "plant-gw.local", "example.com"])
def test_open_bind_needs_a_token(host: str) -> None:
    with pytest.raises(SecurityError, match="without --token-file"):
        check_bind(host, None)
    check_bind(host, "x" * 20)


def test_token_file(tmp_path) -> None:
    good = tmp_path / "token"
    good.write_text("  s3cret-token-of-24-chars \n")
    assert read_token(good) == "s3cret-token-of-24-chars"
    short = tmp_path / "short"
    short.write_text("abc")
    with pytest.raises(SecurityError, match="at least 16"):
        read_token(short)
    spaced = tmp_path / "spaced"
    spaced.write_text("two words of a long enough token")
    with pytest.raises(SecurityError, match="one word"):
        read_token(spaced)
    with pytest.raises(SecurityError, match="cannot read"):
        read_token(tmp_path / "missing")


def test_bearer_is_compared_in_constant_time(monkeypatch) -> None:
    calls = []
    real = hmac.compare_digest

    def spy(a: bytes, b: bytes) -> bool:
        calls.append((a, b))
        return real(a, b)

    monkeypatch.setattr(security.hmac, "compare_digest", spy)
    token = "k" * 20
    assert bearer_ok(f"Bearer {token}", token) and calls == [(token.encode(), token.encode())]
    assert not bearer_ok("Bearer " + "j" * 20, token)
    assert not bearer_ok(token, token) and not bearer_ok(None, token) and not bearer_ok("Basic abc", token)
    assert not bearer_ok(f"Bearer {token}", None)  # no token configured: nothing is authorised


def one_line_error(capsys, argv: list[str]) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


def test_cli_refuses_an_open_bind_without_token(capsys) -> None:
    line = one_line_error(capsys, ["serve", "--host", "0.0.0.0"])
    assert line.startswith("frictionwatch serve: error: refusing to listen on 0.0.0.0 without --token-file")


@pytest.mark.parametrize("argv, words", [
    (["serve", "--source", "nope:whatever"], "unknown source"),
    (["serve", "--source", "mcap:replay_logs/demo.mcap#Bad_ID"], "engine id after '#'"),
    (["serve", "--source", "mcap:replay_logs/demo.mcap?loop=2"], "loop must be 0 or 1"),
    (["serve", "--source", "mcap:/nonexistent/x.mcap"], "x.mcap"),
    (["serve", "--port", "70000"], "--port must be 0..65535"),
])
def test_cli_bad_arguments(capsys, argv: list[str], words: str) -> None:
    line = one_line_error(capsys, argv)
    assert line.startswith("frictionwatch serve: error:") and words in line, line


def test_cli_short_token_file(capsys, tmp_path) -> None:
    token = tmp_path / "t"
    token.write_text("short")
    line = one_line_error(capsys, ["serve", "--host", "0.0.0.0", "--token-file", str(token)])
    assert "at least 16 characters" in line
