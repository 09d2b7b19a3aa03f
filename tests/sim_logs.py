"""Simulated replay logs for the tests, made through the CLI as a user makes them (`frictionwatch simulate`)."""

from __future__ import annotations

from pathlib import Path

from frictionwatch.service.cli import main


def simulate_log(path: Path, engine: str, rpm: float, load: float, seed: int, cycles: int,
                 effect: str | None = None) -> Path:
    """``path`` (OUT.mcap, its truth beside it) of ``engine`` at ``rpm`` and ``load`` with one optional effect."""
    args = ["simulate", "--engine", engine, "--rpm", str(rpm), "--load", str(load), "--cycles", str(cycles),
            "--seed", str(seed), "-o", str(path)]
    assert main(args + (["--effect", effect] if effect else [])) == 0
    return path
