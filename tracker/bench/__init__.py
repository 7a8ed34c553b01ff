"""Benchmarks behind ``tracker bench NAME``.

Each benchmark module defines ``add_arguments(parser)``, ``run(args, cfg) ->
int`` and a one-line ``__doc__``. Results go to ``--out`` (default
``build/bench``) as Markdown and JSON, headed by the machine they ran on
(:func:`tracker.bench.machine.describe_machine`).
"""

# name -> module; `tracker bench all` runs them in this order.
BENCHES = {
    "api": "tracker.bench.api",
    "detect": "tracker.bench.detect",
    "protocol": "tracker.bench.protocol",
    "solve": "tracker.bench.solve",
    "soak": "tracker.bench.soak",
    "aberration": "tracker.bench.aberration",
    "track": "tracker.bench.track",
    "device": "tracker.bench.device",
}
