"""The Docker image's recipe, checked without Docker: every dependency pinned in constraints.txt at a version its
requirement accepts, the build context admits what the Dockerfile copies, the service runs as a non-root user on
the port it exposes and its health check asks, and the numba cache is compiled for a generic CPU at build time."""

from __future__ import annotations

import json
import re
import shlex
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name

ROOT = Path(__file__).resolve().parents[1]


def instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of the Dockerfile, continuation lines joined, comments dropped."""
    lines = [ln for ln in (ROOT / "Dockerfile").read_text().splitlines() if not ln.lstrip().startswith("#")]
    text = re.sub(r"\\\n", " ", "\n".join(lines))
    return [(m[1].upper(), m[2].strip()) for m in re.finditer(r"^\s*(\w+)\s+(.*)$", text, re.M)]


def test_constraints_pin_every_dependency_at_an_accepted_version():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    pins = {}
    for line in (ROOT / "constraints.txt").read_text().splitlines():
        if line.strip() and not line.startswith("#"):
            name, version = line.split("==")
            pins[canonicalize_name(name)] = version.strip()
    wanted = [Requirement(r) for r in project["dependencies"] + project["optional-dependencies"]["postgres"]]
    wanted += [Requirement(r) for r in tomllib.loads((ROOT / "pyproject.toml").read_text())["build-system"]["requires"]]
    for req in wanted:
        key = canonicalize_name(req.name)
        assert key in pins, f"{req.name} is not pinned in constraints.txt"
        assert req.specifier.contains(pins[key], prereleases=True), f"{req.name}=={pins[key]} does not meet {req}"
        for extra in req.extras:  # the package an extra brings: psycopg[binary] -> psycopg-binary, dask[distributed]
            candidates = [canonicalize_name(f"{req.name}-{extra}"), canonicalize_name(extra)]  # -> distributed
            assert any(c in pins for c in candidates), f"{req.name}[{extra}]: none of {candidates} is pinned"


def test_the_build_context_admits_what_the_dockerfile_copies():
    admitted = {ln[1:].rstrip("/") for ln in (ROOT / ".dockerignore").read_text().splitlines() if ln.startswith("!")}
    ignore_all = "*" in (ROOT / ".dockerignore").read_text().splitlines()
    for op, args in instructions():
        if op == "COPY":
            *sources, _dest = shlex.split(args)
            for src in sources:
                assert (ROOT / src).exists(), src
                assert not ignore_all or src.rstrip("/") in admitted, f"{src} is copied but .dockerignore leaves it out"


def test_the_service_runs_unprivileged_on_the_port_it_exposes_and_checks():
    ops = instructions()
    users = [args for op, args in ops if op == "USER"]
    assert users and users[-1] not in ("root", "0")
    (expose,) = [args for op, args in ops if op == "EXPOSE"]
    cmd = json.loads(next(args for op, args in ops if op == "CMD"))
    entry = json.loads(next(args for op, args in ops if op == "ENTRYPOINT"))
    argv = entry + cmd
    assert argv[:2] == ["frictionwatch", "serve"]
    assert argv[argv.index("--port") + 1] == expose
    assert argv[argv.index("--host") + 1] == "0.0.0.0" and "--token-file" in argv  # non-loopback needs the token
    source = argv[argv.index("--source") + 1]
    assert (ROOT / source.removeprefix("mcap:").split("?")[0]).exists()
    health = next(args for op, args in ops if op == "HEALTHCHECK")
    assert f"127.0.0.1:{expose}/api/v1/health" in health and "curl" not in health
    # service/healthcheck.py: 'degraded' (lagging, not yet analysing) is healthy for the container
    assert "frictionwatch.service.healthcheck" in health


def test_the_numba_cache_is_compiled_at_build_time_for_a_generic_cpu():
    ops = instructions()
    env_at = next(i for i, (op, args) in enumerate(ops) if op == "ENV" and "NUMBA_CPU_NAME=generic" in args)
    assert "NUMBA_CACHE_DIR=" in ops[env_at][1]
    warm = [i for i, (op, args) in enumerate(ops) if op == "RUN" and "frictionwatch analyze" in args]
    assert warm and warm[0] > env_at  # the warm-up compiles under the settings the service runs with
    user_at = max(i for i, (op, _) in enumerate(ops) if op == "USER")
    assert user_at < warm[0]  # and as the service's user, so the cache stays writable for what it did not reach
    # serve's warm-up of the bundled log's engine (service/warmup.py): what the container's start would compile
    assert "python -m frictionwatch.service.warmup replay_logs/demo.mcap" in ops[warm[0]][1]
