"""The progress bar tells a waiting user what is happening (first-run kernel compilation) once, and only while no
progress has been reported."""

import time

from frictionwatch.service import progress


def test_a_silent_wait_is_explained_once(monkeypatch, capsys):
    monkeypatch.setattr(progress, "NOTE_AFTER_S", 0.05)
    with progress.progress_bar(total=0, desc="analyze demo.mcap") as bar:
        time.sleep(0.3)
        bar.update(1)
    err = capsys.readouterr().err
    assert err.count("compiling the numerical kernels") == 1 and err.startswith("analyze demo.mcap: ")


def test_no_note_when_progress_comes_in_time(monkeypatch, capsys):
    monkeypatch.setattr(progress, "NOTE_AFTER_S", 0.2)
    with progress.progress_bar(total=1.0, desc="simulate k9k-4cyl") as bar:
        bar.set_fraction(0.5)
        time.sleep(0.4)
    assert "compiling" not in capsys.readouterr().err
