"""The whole loop keeps nothing per frame: real pipeline, real solver, real serial link.

The detector's own test (test_detect_memory) shows it allocates nothing per
frame. Here the daemon runs the real Pipeline (detector, lost in space, then
tracking in windows) on a realistic simulated 1600 x 1300 frame and sends ATTITUDE,
CENTROIDS and STATUS through the real link on a pseudo-terminal whose other
end is drained. The Python memory still held after frame 260 exceeds that
after frame 60 by a bounded amount: the loop allocates per frame (results,
packets, snapshots) but keeps none of it.
"""

import dataclasses
import threading
import tracemalloc

import numpy as np
import pytest
from daemon_fakes import FakeSource

from tracker.capture.base import Frame
from tracker.catalogue import load_catalogue
from tracker.config import Config
from tracker.daemon import Daemon, DaemonLink
from tracker.daemon.notify import Notifier
from tracker.pipeline import Pipeline
from tracker.protocol.nullmodem import ReplugPty
from tracker.sim import random_attitude, render_sky

FIRST, LAST = 60, 260


@pytest.mark.slow
def test_the_whole_loop_keeps_nothing_per_frame(tmp_path):
    cfg = Config()
    cfg = dataclasses.replace(
        cfg, link=dataclasses.replace(cfg.link, port=str(tmp_path / "fcu"),
                                      centroids_rate_hz=100.0, status_rate_hz=100.0),
        service=dataclasses.replace(cfg.service, watchdog_s=0.0))
    cat = load_catalogue(cfg.catalogue.path, cfg.catalogue.epoch_year, cfg.catalogue.mag_limit)
    rng = np.random.default_rng(12)
    image = render_sky(cfg.camera, cat, random_attitude(rng), cfg.sim, rng).image

    def frames():
        k = 0
        while True:
            yield Frame(k, f"f{k}", image, 10, 10**12 + k * 10**8)   # 10 fps, standing still
            k += 1

    fc = ReplugPty(tmp_path / "fcu")
    stop = threading.Event()
    drainer = threading.Thread(target=fc.drain_until, args=(stop,), daemon=True)
    drainer.start()
    daemon = Daemon(cfg, source_factory=lambda: FakeSource(frames()), pipeline=Pipeline(cfg),
                    link=DaemonLink(cfg), notifier=Notifier(""))
    held, solved, windowed = {}, [], []

    def on_frame(report):
        solved.append(report.solved)
        windowed.append(any(name.startswith("windows.") for name in report.stages_ms))
        if report.index in (FIRST, LAST):
            held[report.index] = tracemalloc.get_traced_memory()[0]
        if report.index == LAST:
            daemon.request_stop()

    daemon.on_frame = on_frame
    daemon.pipeline.solver  # noqa: B018  (the catalogue and database: start-up, not per frame)
    tracemalloc.start()
    try:
        assert daemon.run() == 0
    finally:
        tracemalloc.stop()
        stop.set()
        drainer.join(5)
        fc.close()
    growth = held[LAST] - held[FIRST]
    print(f"Python memory held: {growth / 1024:.1f} KiB more after {LAST - FIRST} frames")
    assert all(solved[FIRST:])
    assert all(windowed[FIRST:])          # tracked in windows (tracker.identify.windows)
    assert daemon.link.link.stats()["sent_attitude"] > 0
    # 200 frames: 32 KiB is 160 bytes per frame, less than one kept packet (65 bytes
    # of ATTITUDE + the bytes object's 33) plus a list entry per frame would cost.
    assert growth < 32 * 1024
