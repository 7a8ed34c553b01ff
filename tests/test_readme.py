"""The README's commands run as written, and its measured figures name commands a clone has.

- Every ``tracker`` command in the README's ``sh`` blocks parses (the Pi's
  ones included: they are checked, not run).
- The blocks marked ``<!-- test: run -->`` are run with bash, as written,
  in a scratch folder laid out like the clone (its files and folders linked
  in, ``build/`` empty but for ``build/demo``, which ``make demo`` would
  have made), with the venv's ``tracker`` on PATH and a scratch home folder.
  Then what they made is checked: the overlay, the report, the installed
  package's demo and solution, the packets the FC decoded over the socat
  cable, the calibrated camera.
- Every row of the "Measured" table names a command: ``tracker ...`` that
  parses, or ``pytest FILE...`` naming test files that exist, or "same run"
  for the row above's.
"""

import json
import os
import re
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from tracker.attitude import attitude_error, matrix_from_quat
from tracker.cli import build_parser
from tracker.protocol.messages import AttitudeFlag

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
FENCE = re.compile(r"(?P<marker><!-- test: run -->\n)?```sh\n(?P<body>.*?)```", re.S)
NOT_IN_A_CLONE = {".git", ".venv", "build", ".pytest_cache", ".ruff_cache", ".hypothesis"}
REDIRECTS = {">", ">>", "<", "&>", "2>"}
OPERATORS = {"&&", "||", "|", ";", "&", "(", ")"}


def shell_blocks() -> list[tuple[bool, str]]:
    """(marked to run, text) of every ```sh block, in order."""
    return [(bool(m["marker"]), m["body"]) for m in FENCE.finditer(README)]


def command_lines(body: str) -> list[str]:
    """The block's lines, continuations joined, here-document bodies left out."""
    lines, heredoc_end = [], None
    for line in body.replace("\\\n", " ").splitlines():
        if heredoc_end is not None:
            heredoc_end = None if line.strip() == heredoc_end else heredoc_end
            continue
        found = re.search(r"<<-?\s*'?(\w+)'?", line)
        if found:
            heredoc_end = found[1]
        lines.append(line)
    return lines


def tracker_argvs(body: str) -> list[list[str]]:
    """The arguments of every ``tracker`` (or ``.../bin/tracker``) command in a block."""
    argvs = []
    for line in command_lines(body):
        lexer = shlex.shlex(line, posix=True, punctuation_chars=True)
        lexer.whitespace_split, lexer.commenters = True, "#"
        words, segment = list(lexer), []
        for word in [*words, ";"]:
            if word not in OPERATORS:
                segment.append(word)
                continue
            names = [Path(w).name for w in segment]
            if "tracker" in names:
                args, rest = [], segment[names.index("tracker") + 1:]
                while rest:
                    w = rest.pop(0)
                    if w in REDIRECTS:
                        rest = rest[1:]
                    elif not (w.isdigit() and rest and rest[0] in REDIRECTS):
                        args.append(w)
                argvs.append(args)
            segment = []
    return argvs


def test_every_tracker_command_in_the_readme_parses():
    argvs = [argv for _, body in shell_blocks() for argv in tracker_argvs(body)]
    assert len(argvs) >= 15
    parser = build_parser()
    for argv in argvs:
        try:
            parser.parse_args(argv)
        except SystemExit as exc:
            pytest.fail(f"README: `tracker {' '.join(argv)}` does not parse ({exc})")


def test_the_parser_of_this_test_finds_what_it_should():
    body = ("sudo -u st /opt/st/.venv/bin/tracker selftest --config /etc/c.yaml  # note\n"
            "cat > x.yaml <<'EOF'\ntracker: not a command\nEOF\n"
            "tracker run --replay a \\\n  --port p 2> log & service=$!\n")
    assert tracker_argvs(body) == [["selftest", "--config", "/etc/c.yaml"],
                                   ["run", "--replay", "a", "--port", "p"]]


# --- the blocks that run --------------------------------------------------------------

def runnable() -> list:
    """The marked blocks, named by their place and first tracker subcommand."""
    out = []
    for n, (marked, body) in enumerate(shell_blocks()):
        if marked:
            first = (tracker_argvs(body) or [["sh"]])[0][0]
            out.append(pytest.param(body, id=f"block{n}-{first}"))
    return out


@pytest.fixture(scope="module", name="clone")
def fixture_clone(tmp_path_factory):
    """A folder laid out like the clone after `make demo` (a short one), and its environment."""
    folder = tmp_path_factory.mktemp("readme")
    for path in ROOT.iterdir():
        if path.name not in NOT_IN_A_CLONE and not path.name.endswith(".egg-info"):
            (folder / path.name).symlink_to(path)
    home = tmp_path_factory.mktemp("home")
    env = dict(os.environ, HOME=str(home),
               PATH=f"{Path(sys.executable).parent}{os.pathsep}{os.environ['PATH']}")
    env.pop("VIRTUAL_ENV", None)
    demo = subprocess.run(["tracker", "demo", "--frames", "4", "--out", "build/demo"], cwd=folder,
                          env=env, capture_output=True, text=True, stdin=subprocess.DEVNULL)
    assert demo.returncode == 0, demo.stderr[-2000:]
    return folder, env


@pytest.mark.slow
@pytest.mark.parametrize("body", runnable())
def test_the_marked_blocks_run_as_written(body, clone):
    folder, env = clone
    if "socat" in body and shutil.which("socat") is None:
        if os.environ.get("CI"):
            pytest.fail("socat is missing in CI (.ci/run installs Debian's socat)")
        pytest.skip("socat not installed (apt-get install -y socat); .ci/run installs it")
    proc = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", body], cwd=folder, env=env,
                          capture_output=True, text=True, stdin=subprocess.DEVNULL,
                          timeout=600)   # a hang guard only: every block ends by itself
    assert proc.returncode == 0, f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    assert "Traceback" not in proc.stderr
    for marker, check in CHECKS.items():
        if marker in body:
            check(folder, proc.stdout)


def check_overlay(folder: Path, out: str) -> None:
    (picture,) = (folder / "build/overlays").glob("orion_belt*.png")
    assert "solved" in out and picture.stat().st_size > 10_000


def check_report(folder: Path, out: str) -> None:
    page = (folder / "build/report/index.html").read_text()
    assert "f0003.png" in page and "<svg" in page


def check_installed(folder: Path, out: str) -> None:
    """The demo and the solution came from the venv in the scratch home, not the clone."""
    assert "demo: OK" in out and "frames processed     10 of 10" in out
    assert "SolveResult(ok=True, ra_deg=84.0" in out


def check_laptop(folder: Path, out: str) -> None:
    """The FC decoded valid ATTITUDE packets over the socat cable, each within 10 arcsec
    of a frame's truth (the replay loops, so frame ids run past the files)."""
    frames = folder / "build/laptop/frames"
    truths = [json.loads(p.read_text())["q"] for p in sorted(frames.glob("*.truth.json"))]
    packets = [json.loads(line) for line in (folder / "build/laptop/fc.jsonl").read_text()
               .splitlines() if line.strip()]
    attitudes = [p["values"] for p in packets if p.get("name") == "ATTITUDE"
                 and p["values"]["flags"] & AttitudeFlag.VALID]
    assert len(truths) == 20 and len(attitudes) >= 20
    for v in attitudes:
        q = matrix_from_quat([v["q_w"], v["q_x"], v["q_y"], v["q_z"]])
        best = min(attitude_error(q, matrix_from_quat(t))[0] for t in truths)
        assert best * 206265 < 10, v


def check_own_camera(folder: Path, out: str) -> None:
    """Calibrated from the 35 mm label: the truth's scale, 40.31 arcsec/px, is 35.3 mm."""
    camera = yaml.safe_load((folder / "my-camera-calibrated.yaml").read_text())["camera"]
    assert camera["focal_length_mm"] == pytest.approx(35.29, abs=0.05)
    assert "4 solved (100.0 %)" in out


CHECKS = {"--overlay build/overlays": check_overlay, "--report build/report": check_report,
          "pip install .": check_installed, "socat": check_laptop,
          "my-camera.yaml": check_own_camera}


# --- the measured figures -----------------------------------------------------------

def measured_rows() -> list[tuple[str, str]]:
    table = README.split("<!-- results:start -->", 1)[1].split("<!-- results:end -->", 1)[0]
    rows = [line.split(" | ") for line in table.splitlines() if line.startswith("| ")]
    return [(cells[0].lstrip("| "), cells[1]) for cells in rows[2:]]


def test_every_measured_figure_names_a_command_that_a_clone_has():
    rows = measured_rows()
    assert len(rows) >= 10
    parser = build_parser()
    for what, command in rows:
        if command.startswith("same run"):
            continue
        named = re.findall(r"`([^`]+)`", command)
        assert named, f"Measured row {what!r}: no command in {command!r}"
        for text in named:
            argv = shlex.split(text)
            if argv[0] == "tracker":
                parser.parse_args(argv[1:])
            elif argv[0] == "pytest":
                collect = subprocess.run([sys.executable, "-m", "pytest", "--collect-only", "-q",
                                          "-p", "no:cacheprovider", *argv[1:]],
                                         cwd=ROOT, capture_output=True, text=True)
                assert collect.returncode == 0, f"`{text}` selects no test: {collect.stdout[-800:]}"
            else:
                pytest.fail(f"Measured row {what!r}: `{text}` is not a command")
