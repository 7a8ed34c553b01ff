"""Never a traceback: every subcommand over a corpus of bad files, folders, configurations
and arguments, each run as a user runs it (the installed console script, a subprocess).

A case passes when the program exits with the status it should (2 for a mistake the user
can fix, said in one line; 0 when replay reports a bad frame and goes on; 1 where the
command's own contract says so) and nothing on stderr contains "Traceback". The table
:data:`CASES` is the corpus: one row per run, easy to extend when a subcommand is added
(add its rows; `test_every_subcommand_is_in_the_corpus` fails until you do).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import pytest
from bad_files import black_png, npy_claiming, png_claiming

from tracker.catalogue import default_catalogue_path
from tracker.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent
REAL = ROOT / "tests" / "data" / "real" / "cedar-solve"
SCRIPT = Path(sys.executable).parent / "tracker"
HANG_GUARD_S = 120      # a run still going after this is a hang (a FIFO read, a retry loop)

# YAML documents a user (or an attacker) might hand over as --config.
BAD_YAML = {
    "alias_bomb": "".join(
        f"{n}: &{n} [{', '.join([f'*{p}'] * 9) if p else ', '.join(['lol'] * 9)}]\n"
        for p, n in zip([None, *"abcdefgh"], "abcdefghi", strict=True)),
    "deep": "camera: " + "[" * 5000 + "]" * 5000 + "\n",
    "big_int": "camera:\n  width: " + "9" * 5000 + "\n",
    "duplicate": "camera:\n  width: 100\n  width: 200\n",
    "exposure_order": "capture:\n  exposure_min_us: 200000\n  exposure_max_us: 100000\n",
    "gain_order": "capture:\n  gain: 20\n  gain_max: 16\n",
    "retry_order": "service:\n  retry_initial_s: 10\n  retry_max_s: 8\n",
    "backoff_order": "link:\n  reopen_backoff_s: 5\n  reopen_backoff_max_s: 1\n",
    "huge_camera": "camera:\n  width: 65535\n  height: 65535\n",
    "python_tag": "camera:\n  width: !!python/object/apply:os.system ['echo hi']\n",
    "not_a_mapping": "- 1\n- 2\n",
    "syntax": "camera: {width: 3\n",
    "unknown_key": "camera:\n  widht: 1600\n",
    "nan": "camera:\n  focal_length_mm: .nan\n",
    "missing_catalogue": "catalogue:\n  path: {tmp}/nothing.npz\n",
    "corrupt_catalogue": "catalogue:\n  path: {corrupt_catalogue}\n",
    "missing_database": "identify:\n  database: {tmp}/nothing.npz\n",
}


@pytest.fixture(scope="module", name="corpus")
def fixture_corpus(tmp_path_factory) -> dict[str, str]:
    """Every bad thing, made in a temporary folder; name -> path (or text)."""
    tmp = tmp_path_factory.mktemp("corpus")
    c: dict[str, str] = {"tmp": str(tmp), "real": str(REAL)}

    def put(name: str, data: bytes) -> None:
        (tmp / name).write_bytes(data)
        c[name.replace(".", "_")] = str(tmp / name)

    put("bomb.png", png_claiming(60000, 60000))
    put("bomb.npy", npy_claiming((100000, 100000)))
    put("wide.png", black_png(20000, 20000))
    jpeg = (REAL / "orion_belt.jpg").read_bytes()
    put("half.jpg", jpeg[: len(jpeg) // 2])
    put("mended.jpg", jpeg[: len(jpeg) // 2] + b"\xff\xd9")
    put("garbage.png", bytes(range(256)) * 4)
    put("text.npy", b"just some text\n")
    put("empty.png", b"")
    os.mkfifo(tmp / "fifo.png")
    c["fifo_png"] = str(tmp / "fifo.png")
    os.mkfifo(tmp / "fifo.yaml")
    c["fifo_yaml"] = str(tmp / "fifo.yaml")
    (tmp / "empty_dir").mkdir()
    c["empty_dir"] = str(tmp / "empty_dir")
    (tmp / "a_file").write_text("not a folder")
    c["a_file"] = str(tmp / "a_file")
    # a folder of bad frames beside one good one: replay goes on through all
    bad = tmp / "bad_frames"
    bad.mkdir()
    for name in ("bomb.png", "bomb.npy", "half.jpg", "mended.jpg", "garbage.png", "empty.png"):
        shutil.copyfile(tmp / name, bad / name)
    shutil.copyfile(REAL / "orion_belt.jpg", bad / "zz_good.jpg")
    c["bad_frames"] = str(bad)
    # frames whose record's absolute time is not a time
    badtime = tmp / "bad_time"
    badtime.mkdir()
    shutil.copyfile(REAL / "orion_belt.jpg", badtime / "f.jpg")
    (badtime / "frames.jsonl").write_text('{"file": "f.jpg", "utc": "2026-02-30T00:00:00Z"}\n')
    c["bad_time"] = str(badtime)
    # validate/calibrate inputs: a frame with a truth file that is not JSON, one with none
    shutil.copyfile(REAL / "orion_belt.jpg.centroids.json", tmp / "lone.jpg.centroids.json")
    c["lone_centroids"] = str(tmp / "lone.jpg.centroids.json")
    shutil.copyfile(REAL / "orion_belt.jpg.centroids.json", tmp / "badtruth.jpg.centroids.json")
    (tmp / "badtruth.jpg.truth.json").write_text("{not json")
    c["badtruth_centroids"] = str(tmp / "badtruth.jpg.centroids.json")
    (tmp / "wrongtruth.jpg.truth.json").write_text(
        '{"stars": [{"x": "a", "y": 1, "ra_deg": 1, "dec_deg": 2}]}')
    shutil.copyfile(REAL / "orion_belt.jpg.centroids.json", tmp / "wrongtruth.jpg.centroids.json")
    c["wrongtruth_centroids"] = str(tmp / "wrongtruth.jpg.centroids.json")
    (tmp / "bad.centroids.json").write_text('{"stars": 5}')
    c["bad_centroids"] = str(tmp / "bad.centroids.json")
    # a catalogue whose bytes no longer match its checksum
    src = default_catalogue_path()
    data = bytearray(src.read_bytes())
    data[len(data) // 2] ^= 1
    (tmp / "stars.npz").write_bytes(bytes(data))
    shutil.copyfile(f"{src}.sha256", tmp / "stars.npz.sha256")
    c["corrupt_catalogue"] = str(tmp / "stars.npz")
    for name, text in BAD_YAML.items():
        for key in ("tmp", "corrupt_catalogue"):
            text = text.replace(f"{{{key}}}", c[key])
        (tmp / f"{name}.yaml").write_text(text)
        c[f"yaml_{name}"] = str(tmp / f"{name}.yaml")
    (tmp / "latin1.yaml").write_bytes(b"camera:\n  width: \xe9\n")
    c["yaml_latin1"] = str(tmp / "latin1.yaml")
    (tmp / "small_camera.yaml").write_text("camera: {width: 512, height: 512}\n")
    c["yaml_small_camera"] = str(tmp / "small_camera.yaml")
    (tmp / "telescope.yaml").write_text("camera: {focal_length_mm: 3000}\n")   # 0.1 deg
    c["yaml_telescope"] = str(tmp / "telescope.yaml")
    return c


def _config_cases() -> list[tuple]:
    # a configuration naming a missing file is valid YAML: `tracker config` prints it (0);
    # the commands that load the file say what is wrong with it (below)
    rows = [(f"config-{name}", ["config", "--config", f"{{yaml_{name}}}"],
             0 if name.startswith(("missing_", "corrupt_")) else 2, None)
            for name in (*BAD_YAML, "latin1")]
    rows += [("config-fifo", ["config", "--config", "{fifo_yaml}"], 2, "named pipe"),
             ("config-dev-zero", ["config", "--config", "/dev/zero"], 2, "character device"),
             ("config-folder", ["config", "--config", "{tmp}"], 2, "a folder"),
             ("config-missing", ["config", "--config", "{tmp}/none.yaml"], 2, "no such file")]
    return rows


# (id, argv, expected exit status, text the last stderr line must contain or None)
CASES: list[tuple[str, list[str], int, str | None]] = [
    # -- no or wrong subcommand ---------------------------------------------------------
    ("bare", [], 2, "required"),
    ("unknown-command", ["launch"], 2, "invalid choice"),
    *_config_cases(),
    # -- replay: bad frames are records, bad paths and options one line -------------------
    ("replay-bomb-png", ["replay", "{bomb_png}", "--jsonl", "{tmp}/o1.jsonl"], 0, "unreadable"),
    ("replay-bomb-npy", ["replay", "{bomb_npy}", "--jsonl", "{tmp}/o2.jsonl"], 0, "unreadable"),
    ("replay-wide-png", ["replay", "{wide_png}", "--quiet"], 0, "unreadable"),
    ("replay-half-jpeg", ["replay", "{half_jpg}"], 0, "unreadable"),
    ("replay-mended-jpeg", ["replay", "{mended_jpg}"], 0, "unreadable"),
    ("replay-bad-folder", ["replay", "{bad_frames}", "--overlay", "{tmp}/ov", "--report",
                           "{tmp}/rep", "--jsonl", "{tmp}/o3.jsonl"], 0, "report"),
    ("replay-fifo", ["replay", "{fifo_png}"], 2, "named pipe (FIFO)"),
    ("replay-dev-null", ["replay", "/dev/null"], 2, "character device"),
    ("replay-empty-folder", ["replay", "{empty_dir}"], 2, "no image files"),
    ("replay-missing", ["replay", "{tmp}/nothing"], 2, "no such file or folder"),
    ("replay-overlay-is-a-file", ["replay", "{bad_frames}", "--overlay", "{a_file}"], 2,
     "is a file, expected a folder"),
    ("replay-report-is-a-file", ["replay", "{bad_frames}", "--report", "{a_file}"], 2,
     "is a file, expected a folder"),
    ("replay-jsonl-is-a-folder", ["replay", "{bad_frames}", "--jsonl", "{tmp}"], 2,
     "is a folder"),
    ("replay-report-loop", ["replay", "{bad_frames}", "--report", "{tmp}/r2", "--loop"], 2,
     "leave out --loop"),
    ("replay-fps-nan", ["replay", "{bad_frames}", "--fps", "nan"], 2, "finite"),
    ("replay-bad-utc", ["replay", "{bad_time}"], 2, "frames.jsonl line 1: utc"),
    ("replay-missing-catalogue", ["replay", "{bad_frames}", "--config",
                                  "{yaml_missing_catalogue}"], 2, "catalogue file not found"),
    ("replay-corrupt-catalogue", ["replay", "{bad_frames}", "--config",
                                  "{yaml_corrupt_catalogue}"], 2, "SHA-256 mismatch"),
    ("replay-missing-database", ["replay", "{bad_frames}", "--config",
                                 "{yaml_missing_database}"], 2, "nothing.npz"),
    ("replay-alias-bomb", ["replay", "{bad_frames}", "--config", "{yaml_alias_bomb}"], 2,
     "aliases"),
    # -- run (the service) ------------------------------------------------------------------
    ("run-bad-frames", ["run", "--replay", "{bad_frames}", "--frames", "7", "--port",
                        "loop://"], 0, None),
    ("run-empty-folder", ["run", "--replay", "{empty_dir}", "--port", "loop://"], 2,
     "no image files"),
    ("run-dev-null", ["run", "--replay", "/dev/null", "--port", "loop://"], 2,
     "character device"),
    ("run-fifo", ["run", "--replay", "{fifo_png}", "--port", "loop://"], 2, "named pipe"),
    ("run-missing-catalogue", ["run", "--replay", "{bad_frames}", "--port", "loop://",
                               "--config", "{yaml_missing_catalogue}"], 2,
     "catalogue file not found"),
    ("run-corrupt-catalogue", ["run", "--replay", "{bad_frames}", "--port", "loop://",
                               "--config", "{yaml_corrupt_catalogue}"], 2, "SHA-256 mismatch"),
    ("run-fps-nan", ["run", "--replay", "{bad_frames}", "--fps", "nan"], 2, "finite"),
    ("run-bad-utc", ["run", "--replay", "{bad_time}", "--port", "loop://"], 2,
     "no such date"),
    ("run-frames-negative", ["run", "--replay", "{bad_frames}", "--frames", "-3"], 2,
     "0 or more"),
    ("run-bad-config", ["run", "--config", "{yaml_exposure_order}"], 2, "exposure_min_us"),
    # -- record ------------------------------------------------------------------------------
    ("record-bad-frames", ["record", "--replay", "{bad_frames}", "--out", "{tmp}/rec",
                           "--frames", "2", "--config", "{yaml_small_camera}",
                           "--min-free-mb", "0"], 0, None),
    ("record-out-is-a-file", ["record", "--replay", "{bad_frames}", "--out", "{a_file}"], 2,
     "is a file"),
    ("record-empty-folder", ["record", "--replay", "{empty_dir}", "--out", "{tmp}/rec2"], 2,
     "no image files"),
    ("record-no-camera", ["record", "--out", "{tmp}/rec3"], 2, "no frames given"),
    ("record-every-zero", ["record", "--out", "{tmp}/rec4", "--every", "0"], 2, "1 or more"),
    ("record-min-free-nan", ["record", "--out", "{tmp}/rec5", "--min-free-mb", "nan"], 2,
     "finite"),
    # -- focus -------------------------------------------------------------------------------
    ("focus-bad-frames", ["focus", "--replay", "{bad_frames}", "--png", "{tmp}/focus.png",
                          "--config", "{yaml_small_camera}"], 0, None),
    ("focus-bad-grid", ["focus", "--replay", "{bad_frames}", "--grid", "0x3"], 2, "1 to 32"),
    ("focus-empty-folder", ["focus", "--replay", "{empty_dir}"], 2, "no image files"),
    ("focus-png-in-a-file", ["focus", "--replay", "{bad_frames}", "--png", "{a_file}/f.png",
                             "--config", "{yaml_small_camera}"], 2, "--png"),
    ("focus-no-camera", ["focus", "--frames", "1"], 2, "no frames given"),
    ("focus-frames-negative", ["focus", "--frames", "-1"], 2, None),
    # -- simulate ----------------------------------------------------------------------------
    ("simulate-out-is-a-file", ["simulate", "--out", "{a_file}"], 2, None),
    ("simulate-utc-2300", ["simulate", "--out", "{tmp}/sim", "--utc", "2300-01-01T00:00:00Z"],
     2, "outside 1972-2200"),
    ("simulate-velocity-huge", ["simulate", "--out", "{tmp}/sim", "--utc",
                                "2030-01-01T00:00:00Z", "--observer-velocity-km-s", "1e9", "0",
                                "0"], 2, "within +-200"),
    ("simulate-huge-camera", ["simulate", "--out", "{tmp}/sim", "--config",
                              "{yaml_huge_camera}"], 2, "pixels"),
    ("simulate-frames-zero", ["simulate", "--out", "{tmp}/sim", "--frames", "0"], 2, ">= 1"),
    ("simulate-ra-nan", ["simulate", "--out", "{tmp}/sim", "--ra", "nan", "--dec", "0",
                         "--roll", "0"], 2, "finite"),
    ("simulate-missing-catalogue", ["simulate", "--out", "{tmp}/sim", "--config",
                                    "{yaml_missing_catalogue}"], 2, "catalogue file not found"),
    # -- demo, bench, selftest ---------------------------------------------------------------
    ("demo-frames-zero", ["demo", "--frames", "0"], 2, "1 or more"),
    ("demo-out-is-a-file", ["demo", "--out", "{a_file}", "--frames", "2"], 2, None),
    ("demo-bad-config", ["demo", "--config", "{yaml_deep}"], 2, "nesting"),
    ("bench-unknown", ["bench", "nonsense"], 2, "invalid choice"),
    ("bench-bad-config", ["bench", "protocol", "--config", "{yaml_duplicate}"], 2, "second time"),
    ("selftest-bad-config", ["selftest", "--config", "{yaml_big_int}"], 2, "characters"),
    ("selftest-missing-catalogue", ["selftest", "--config", "{yaml_missing_catalogue}"], 1,
     None),
    # -- database ------------------------------------------------------------------------
    ("database-no-action", ["database"], 2, "required"),
    ("database-unknown-action", ["database", "frobnicate"], 2, "invalid choice"),
    ("database-cache-is-a-file", ["database", "build", "--cache-dir", "{a_file}"], 2,
     "cannot write the pattern database"),
    ("database-field-too-narrow", ["database", "build", "--config", "{yaml_telescope}",
                                   "--cache-dir", "{tmp}/db"], 2, "outside the 3-80 deg"),
    ("database-missing-catalogue", ["database", "build", "--config",
                                    "{yaml_missing_catalogue}", "--cache-dir", "{tmp}/db"], 2,
     "catalogue file not found"),
    ("database-bad-config", ["database", "list", "--config", "{yaml_duplicate}"], 2,
     "second time"),
    # -- monitor -----------------------------------------------------------------------------
    ("monitor-no-port", ["monitor"], 2, "no serial port given"),
    ("monitor-port-after-send", ["monitor", "--send", "ping", "{tmp}/no-such-port"], 2,
     "cannot open"),
    ("monitor-bad-mode", ["monitor", "loop://", "--send", "set-mode", "flying"], 2,
     "found 'flying', expected standby"),
    ("monitor-bad-exposure", ["monitor", "loop://", "--send", "set-exposure", "-5"], 2,
     "does not fit"),
    ("monitor-missing-argument", ["monitor", "loop://", "--send", "set-output", "attitude"],
     2, "expected set-output MESSAGE HZ"),
    ("monitor-dev-null", ["monitor", "/dev/null", "--duration", "0.2"], 2, "cannot open"),
    ("monitor-count-negative", ["monitor", "loop://", "--count", "-1"], 2, "0 or more"),
    ("monitor-log-is-a-folder", ["monitor", "loop://", "--log", "{tmp}"], 2, "is a folder"),
    # -- calibrate and validate ----------------------------------------------------------------
    ("calibrate-empty-folder", ["calibrate", "{empty_dir}", "--out", "{tmp}/c.yaml"], 2,
     "no images or centroid lists"),
    ("calibrate-bomb", ["calibrate", "{bomb_png}", "--out", "{tmp}/c.yaml"], 2, "60000x60000"),
    ("calibrate-half-jpeg", ["calibrate", "{half_jpg}", "--out", "{tmp}/c.yaml"], 2,
     "truncated JPEG"),
    ("calibrate-fifo", ["calibrate", "{fifo_png}", "--out", "{tmp}/c.yaml"], 2, "named pipe"),
    ("calibrate-bad-centroids", ["calibrate", "{bad_centroids}", "--out", "{tmp}/c.yaml"], 2,
     "not a centroid list"),
    ("calibrate-scale-nan", ["calibrate", "{lone_centroids}", "--out", "{tmp}/c.yaml",
                             "--scale-range", "nan"], 2, "finite"),
    ("calibrate-out-is-a-folder", ["calibrate", "{real}/orion_belt.jpg.centroids.json",
                                   "--config", "{real}/orion_belt.yaml", "--out", "{tmp}"], 2,
     None),
    ("validate-empty-folder", ["validate", "{empty_dir}"], 2, "no images or centroid lists"),
    ("validate-no-truth", ["validate", "{lone_centroids}"], 2, "truth file not found"),
    ("validate-truth-not-json", ["validate", "{badtruth_centroids}"], 2, "not JSON"),
    ("validate-truth-wrong", ["validate", "{wrongtruth_centroids}", "--config",
                              "{real}/orion_belt.yaml"], 2, "a star without"),
    ("validate-bomb", ["validate", "{bomb_npy}"], 2, None),
    ("validate-refs-zero", ["validate", "--affine", "--refs", "0", "{lone_centroids}"], 2,
     "1 or more"),
    ("validate-missing-catalogue", ["validate", "{real}/orion_belt.jpg.centroids.json",
                                    "--config", "{yaml_missing_catalogue}"], 2,
     "catalogue file not found"),
    ("validate-json-is-a-folder", ["validate", "{real}/orion_belt.jpg.centroids.json",
                                   "--config", "{real}/orion_belt.yaml", "--json", "{tmp}"], 2,
     "is a folder"),
]


def _run(argv: list[str], cwd: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONFAULTHANDLER": "", "COLUMNS": "100"}
    return subprocess.run([str(SCRIPT), *argv], capture_output=True, text=True, cwd=cwd,
                          stdin=subprocess.DEVNULL, timeout=HANG_GUARD_S, env=env)


def test_every_subcommand_is_in_the_corpus():
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    covered = {argv[0] for _, argv, _, _ in CASES if argv}
    assert set(sub.choices) <= covered, set(sub.choices) - covered


@pytest.mark.slow
def test_no_traceback_anywhere_in_the_corpus(corpus):
    assert SCRIPT.exists(), f"{SCRIPT}: the console script is not installed (make test)"
    runs = [(case_id, [a.format(**corpus) for a in argv], want, text)
            for case_id, argv, want, text in CASES]
    with ThreadPoolExecutor(max_workers=2) as pool:
        done = list(pool.map(lambda r: (r, _run(r[1], corpus["tmp"])), runs))
    failures = []
    for (case_id, argv, want, text), proc in done:
        err = proc.stderr
        last = err.strip().splitlines()[-1] if err.strip() else ""
        problems = []
        if "Traceback" in err:
            problems.append("a traceback")
        if proc.returncode != want:
            problems.append(f"exit {proc.returncode}, expected {want}")
        if want == 2 and (len(last) > 400 or not last):
            problems.append(f"a last stderr line of {len(last)} characters")
        if text is not None and text not in last and text not in proc.stdout:
            problems.append(f"{text!r} not said")
        if problems:
            failures.append(f"{case_id}: {', '.join(problems)}\n    $ tracker {' '.join(argv)}"
                            f"\n    stderr: {err.strip()[-600:]}")
    assert not failures, f"{len(failures)} of {len(runs)} cases failed:\n" + "\n".join(failures)
