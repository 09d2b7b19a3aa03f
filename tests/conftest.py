"""One BLAS thread per test process, as the service runs (service/__init__.py): two xdist workers on a 2-core box
each with OpenBLAS's own threads spinning doubled the suite's time (test_condition + test_gain_watch with -n 2:
54 s against 25 s single-threaded). Set before any test module imports numpy; `make test` sets it for the whole
process tree too."""

import os

import pytest

from tests import kernel_manifest

for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")


def pytest_collection_modifyitems(config, items):
    """The modules holding a test marked ``slow`` are collected first, each module's tests kept together and in
    order: `make test`'s two workers are dealt whole files in collection order (xdist --dist loadfile), so the
    suite's last files are short ones, not one worker finishing a 60-second file while the other waits."""
    slow = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow") is not None}
    items.sort(key=lambda item: item.nodeid.split("::")[0] not in slow)  # stable: the order within each group kept


_RECORDER = pytest.StashKey[kernel_manifest.Recorder]()
_SHARES = pytest.StashKey[list]()


def pytest_configure(config):
    config.stash[_SHARES] = []
    if kernel_manifest.RECORD:
        worker = getattr(config, "workerinput", None)
        name = worker["workerid"] if worker else "controller"
        config.stash[_RECORDER] = kernel_manifest.Recorder(kernel_manifest.MANIFEST.with_suffix(f".{name}.part"))


@pytest.fixture(scope="session", autouse=True)
def _kernels_compiled_once(request, tmp_path_factory):
    """Under `make test`'s workers: this worker's share of the suite's numba kernels, before its first test, so the
    two workers do not each compile every kernel (tests/kernel_manifest.py); each marks what it compiled in the
    run's temporary folder (the workers' own folders' parent), where the other looks before compiling a kernel that
    calls it. Nothing in a single process."""
    worker = getattr(request.config, "workerinput", None)
    if worker is None or kernel_manifest.RECORD:
        return
    kernels = kernel_manifest.load()
    if kernels:  # none (no manifest, another numba): nothing to do or to say
        index = int(worker["workerid"].removeprefix("gw"))
        done = tmp_path_factory.getbasetemp().parent / "kernels-compiled"
        request.config.workeroutput["kernel_share"] = kernel_manifest.compile_share(
            kernels, index, int(worker["workercount"]), done)


def pytest_sessionfinish(session):
    """Recording (FW_KERNEL_MANIFEST=record): the controller merges the processes' parts at the end."""
    if kernel_manifest.RECORD and not hasattr(session.config, "workerinput"):
        kernel_manifest.merge(kernel_manifest.parts())


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    share = getattr(node, "workeroutput", {}).get("kernel_share")
    if share:
        node.config.stash[_SHARES].append((node.gateway.id, share))


def pytest_terminal_summary(terminalreporter, config):
    for worker, share in sorted(config.stash.get(_SHARES, [])):
        terminalreporter.write_line(f"{worker}: {share['compiled']} kernels compiled (or loaded) before its first "
                                    f"test in {share['seconds']} s ({share['waited']} s of it waiting for the other's "
                                    f"callees; {share.get('dealt_s')} s as recorded); {share['at_import']} compiled "
                                    f"when imported (explicit signatures), "
                                    f"{share['stale']} in the manifest no longer fit")
