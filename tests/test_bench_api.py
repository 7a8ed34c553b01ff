"""`tracker bench api`: the library call against the pipeline it wraps, reported as files."""

import json

from tracker.cli import main


def test_bench_api_solves_every_frame_and_reports_the_ratio(tmp_path, capsys):
    assert main(["bench", "api", "--frames", "3", "--out", str(tmp_path)]) == 0
    report = json.loads((tmp_path / "api.json").read_text())
    assert report["solved"] == 3 and report["first_call_ok"]
    # 1-sigma sizes at 16 mm are ~1.6 arcsec across and ~12 about the boresight
    assert report["rms_cross_arcsec"] < 8 and report["rms_roll_arcsec"] < 60
    assert set(report["times"]) == {"api_array", "pipeline", "api_file"}
    assert report["api_over_pipeline"] > 0 and report["machine"]["cores"]
    text = (tmp_path / "api.md").read_text()
    assert "| `tracker.solve(array)` |" in text and "solved 3 of 3" in text
    assert text in capsys.readouterr().out
