"""A serve start that fails after an engine began its run (a later source cannot be opened) leaves no run behind:
the next start is numbered as if it had not happened, so the run before it still counts as stopped cleanly."""

from __future__ import annotations

from frictionwatch.service.cli import main
from frictionwatch.service.store import open_store

from tests.service.serve_helpers import DEMO


def test_a_failed_start_forgets_the_run_it_began(tmp_path, capsys):
    args = ["serve", "--port", "0", "--data-dir", str(tmp_path), "--source", f"mcap:{DEMO}#a",
            "--source", f"mcap:{tmp_path / 'missing.mcap'}#b"]
    assert main(args) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "missing.mcap" in err[0], err
    store = open_store(str(tmp_path / "frictionwatch.db"))
    try:
        assert store.runs("a") == []  # engine a attached (run 1 begun) before b failed: forgotten
        store.register_engine("a", store.model_versions("a")[-1]["engine_toml"])
        assert store.begin_run("a").run_id == 1
    finally:
        store.close()
