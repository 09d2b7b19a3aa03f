"""serve's HTTP stack (service/serve.http_stack, design note 146): httptools and uvloop where installed, each else its
pure-Python stand-in (h11, asyncio), and what is missing named for the line serve prints at start."""

from __future__ import annotations

import importlib.util

import pytest
from frictionwatch.service import serve


def test_the_fast_pair_when_installed() -> None:
    pytest.importorskip("httptools")
    pytest.importorskip("uvloop")
    assert serve.http_stack() == ("httptools", "uvloop", "")


@pytest.mark.parametrize(("gone", "expected"), [
    ({"httptools"}, ("h11", "uvloop", "httptools")),
    ({"uvloop"}, ("httptools", "asyncio", "uvloop")),
    ({"httptools", "uvloop"}, ("h11", "asyncio", "httptools and uvloop")),
])
def test_each_missing_module_falls_back_and_is_named(monkeypatch, gone: set[str], expected: tuple) -> None:
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name in gone else object())
    assert serve.http_stack() == expected
