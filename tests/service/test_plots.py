"""`analyze --plot` never draws a prior or a share as a measurement (issue 25 item 4): the friction-vs-angle curves
follow the figure status the JSON reports (service.plots.angle_curves)."""

from __future__ import annotations

from pathlib import Path

import pytest
from frictionwatch.core.monitor.report.run_summary import end_of_run_status
from frictionwatch.core.types import LoadSample
from frictionwatch.drivers.logs.mcap_log import LogReader, LogWriter
from frictionwatch.service.cli import main
from frictionwatch.service.pipeline import analyze_log
from frictionwatch.service.plots import angle_curves


def _simulate(folder: Path, name: str, cycles: int, *extra: str) -> Path:
    out = folder / f"{name}.mcap"
    assert main(["simulate", "--engine", "k9k-4cyl", "--rpm", "1700", "--load", "0.8", "--cycles", str(cycles),
                 "--seed", "4", *extra, "-o", str(out)]) == 0
    return out


@pytest.fixture(scope="module")
def logs(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("plots")
    short = _simulate(folder, "short", 8)  # fewer than the warm-up cycles: the engine's figure is the prior
    measured = _simulate(folder, "measured", 40)
    noload = folder / "noload.mcap"  # friction unresolved: nothing balances the indicated work
    with LogReader(measured) as reader, LogWriter(noload, reader.engine_toml, reader.info) as writer:
        for record in reader.records():
            if not isinstance(record, LoadSample):
                writer.write(record)
    return {"short": short, "measured": measured, "noload": noload}


def _curves(log: Path):
    analysis = analyze_log(log)
    status = end_of_run_status(analysis.results)[2]
    return status, *angle_curves(status)


def test_unresolved_friction_draws_no_curve_and_says_why(logs):
    status, curves, notes = _curves(logs["noload"])
    assert status.engine.status == "unresolved"
    drawn = {c.cylinder for c in curves}
    assert None not in drawn and not any("measured)" in c.label for c in curves if c.cylinder is None)
    assert any(n.startswith("total: unresolved, not drawn") and "no load measurement" in n for n in notes)
    # a cylinder is drawn only as what its own status says
    for k, st in enumerate(status.cylinders, start=1):
        assert (k in drawn) == (st.status in ("measured", "share", "prior"))


def test_the_prior_is_drawn_dashed_and_labelled_as_the_model(logs):
    status, curves, notes = _curves(logs["short"])
    assert status.engine.status == "prior"
    total = [c for c in curves if c.cylinder is None]
    assert len(total) == 1 and not total[0].measured and "prior" in total[0].label and "not measured" in total[0].label
    assert not any(c.measured for c in curves)  # nothing of a prior-only run is solid


def test_measured_figures_are_solid_and_every_figure_is_drawn_or_noted(logs, tmp_path):
    status, curves, notes = _curves(logs["measured"])
    assert status.engine.status == "measured"
    assert [c.measured for c in curves if c.cylinder is None] == [True]
    by_cyl = {c.cylinder: c for c in curves}
    for k, st in enumerate(status.cylinders, start=1):
        if st.status == "measured":
            assert by_cyl[k].measured and by_cyl[k].label == f"cyl {k} (measured)"
        elif k in by_cyl:
            assert not by_cyl[k].measured and st.status in by_cyl[k].label
    assert len(curves) + len(notes) == 1 + len(status.cylinders)
    for name, log in logs.items():  # the command writes its three plots whatever the status
        assert main(["analyze", str(log), "--plot", str(tmp_path / name)]) == 0
        assert sorted(p.name for p in (tmp_path / name).glob("*.png")) == [
            "friction_per_cylinder_trend.png", "friction_torque_vs_angle.png", "speed_measured_vs_model.png"]
