"""The README keeps up with the code: every config key and every command."""

import subprocess
import sys
from pathlib import Path

from tracker.cli import build_parser

ROOT = Path(__file__).resolve().parent.parent


def test_readme_config_table_is_current():
    proc = subprocess.run([sys.executable, str(ROOT / "tools" / "update_readme.py"), "--check"],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr


def test_readme_opens_with_the_two_commands():
    head = (ROOT / "README.md").read_text().split("\n## ", 1)[0]
    assert "make demo" in head and "make test" in head


def test_readme_documents_every_subcommand():
    text = (ROOT / "README.md").read_text()
    sub = next(a for a in build_parser()._actions if a.dest == "command")
    for name in sub.choices:
        assert f"`tracker {name}" in text, f"README does not document `tracker {name}`"
