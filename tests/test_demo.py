"""`tracker demo` (what `make demo` runs): the whole chain on a pseudo-terminal."""

import json

import pytest

from tracker.cli import main


@pytest.mark.slow
def test_demo_runs_to_its_summary_and_the_fc_decodes_every_attitude(tmp_path, capfd):
    assert main(["demo", "--out", str(tmp_path), "--frames", "6"]) == 0
    out = capfd.readouterr().out
    assert "demo summary" in out and "demo: OK" in out
    assert "frames processed     6 of 6" in out
    summary = json.loads((tmp_path / "service.json").read_text())["link"]
    fc = [json.loads(line) for line in (tmp_path / "fc.jsonl").read_text().splitlines()]
    decoded = sum(p["name"] == "ATTITUDE" for p in fc)
    # every attitude sent reached the FC; a frame's only excuses are a stale drop (a loaded
    # machine's first, lost-in-space frame can take longer than link.max_age_ms) and the
    # output rate (a late frame followed at once by the next), both counted
    assert decoded == summary["sent_attitude"] >= 4
    assert decoded + summary.get("dropped_stale_attitude", 0) \
        + summary.get("over_rate_attitude", 0) == 6
    # the frames are aberrated (2026, low Earth orbit): the FC gets the ICRS attitude
    truth = next(line for line in out.splitlines() if "attitude vs truth" in line)
    assert f"over {decoded} solutions" in truth and f"aberration corrected in {decoded})" in truth
    assert float(truth.split("cross-boresight")[1].split()[0]) < 5.0
