"""``tracker bench NAME``: run a benchmark and write its report."""

from __future__ import annotations

import importlib
import sys

from tracker.bench import BENCHES


def register(sub, common) -> None:
    p = sub.add_parser("bench", parents=[common], help=f"run a benchmark ({', '.join(BENCHES)}, "
                       "all) and write Markdown/JSON reports")
    names = p.add_subparsers(dest="bench", metavar="NAME", required=True)
    for name, module in BENCHES.items():
        mod = importlib.import_module(module)
        q = names.add_parser(name, parents=[common], help=(mod.__doc__ or "").strip()
                             .splitlines()[0])
        q.add_argument("--out", default="build/bench", help="folder for the reports")
        mod.add_arguments(q)
        q.set_defaults(func=mod.run)
    q = names.add_parser("all", parents=[common], help="every benchmark, defaults each")
    q.add_argument("--out", default="build/bench", help="folder for the reports")
    q.set_defaults(func=_run_all)


def _run_all(args, cfg) -> int:
    from tracker.cli import build_parser

    worst = 0
    for name in BENCHES:
        sub_args = build_parser().parse_args(["bench", name, "--out", args.out])
        print(f"== tracker bench {name}", file=sys.stderr)
        worst = max(worst, int(sub_args.func(sub_args, cfg) or 0))
    return worst
