"""`tracker demo` (what `make demo` runs): the whole chain on a pseudo-terminal."""

import pytest

from tracker.cli import main


@pytest.mark.slow
def test_demo_runs_to_its_summary_and_the_fc_decodes_every_attitude(tmp_path, capfd):
    assert main(["demo", "--out", str(tmp_path), "--frames", "6"]) == 0
    out = capfd.readouterr().out
    assert "demo summary" in out and "demo: OK" in out
    assert "frames processed     6 of 6" in out
    decoded = next(line for line in out.splitlines() if "packets decoded (FC)" in line)
    assert '"ATTITUDE": 6' in decoded
    # the frames are aberrated (2026, low Earth orbit): the FC gets the ICRS attitude
    truth = next(line for line in out.splitlines() if "attitude vs truth" in line)
    assert "aberration corrected in 6)" in truth
    assert float(truth.split("cross-boresight")[1].split()[0]) < 5.0
