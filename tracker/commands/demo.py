"""``tracker demo``: placeholder until the simulator lands."""


def register(sub, common) -> None:
    sub.add_parser("demo", parents=[common], help="the main job on embedded defaults (pending)")
