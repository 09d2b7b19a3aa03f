"""The wheel pattern read from the TU/e files' own edges (drivers.daq.teeth.wheel_pattern), no wheel assumed: every
one of the 22 files is a 60-2 wheel (README: 58 crossings per revolution, gap ~3.4 pitches with distorted
neighbours), coast-downs and noisy no-load files included."""

from frictionwatch.drivers.daq.raw import read_daq_table
from frictionwatch.drivers.daq.teeth import edge_ticks, wheel_pattern


def test_every_tue_file_reads_as_60_2(realdata):
    files = sorted((realdata / "tue-4gb10-si-encoder-pressure").glob("*.txt.gz"))
    assert len(files) == 22
    for path in files:
        trace = read_daq_table(path)
        seen = wheel_pattern(edge_ticks(trace.wheel_v, trace.sample_rate_hz)[0])
        assert seen is not None and (seen.present, seen.missing) == (58, 2), (path.name, seen)
        assert seen.revolutions >= 8 and seen.agree >= seen.revolutions - 1, (path.name, seen)
