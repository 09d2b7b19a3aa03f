"""The committed replay logs are exactly what the commands in replay_logs/README.md make (byte for byte: the simulator
and the writer are deterministic for a seed), and each one analyses."""

import shlex
from pathlib import Path

import pytest

from service.cli import main

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "replay_logs" / "README.md"


def commands():
    text = README.read_text()
    block = text.split("```sh", 1)[1].split("```", 1)[0]
    return [shlex.split(line) for line in block.splitlines() if line.startswith("frictionwatch ")]


def test_every_committed_log_has_a_command():
    outputs = {Path(c[c.index("-o") + 1]).name for c in commands()}
    committed = {p.name for p in (ROOT / "replay_logs").glob("*.mcap")}
    assert committed == outputs and "demo.mcap" in committed


@pytest.mark.parametrize("argv", commands(), ids=lambda c: Path(c[-1]).stem)
def test_log_is_what_its_command_makes(argv, tmp_path, capsys):
    out = Path(argv[argv.index("-o") + 1])
    fresh = tmp_path / out.name
    args = argv[1:argv.index("-o")] + ["-o", str(fresh)]
    assert main(args) == 0
    assert fresh.read_bytes() == (ROOT / out).read_bytes(), f"{out} differs from what its command makes"
    truth = out.name.removesuffix(".mcap") + ".truth.json"
    assert (tmp_path / truth).read_bytes() == (ROOT / out.parent / truth).read_bytes()
