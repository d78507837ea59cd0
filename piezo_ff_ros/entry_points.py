"""Console-script targets.  Imports are lazy so that ``piezo-ff reproduce`` never loads rclpy."""
from __future__ import annotations

import sys


def driver(argv=None):
    from .nodes.driver import main

    return main(argv)


def compensator(argv=None):
    from .nodes.compensator import main

    return main(argv)


def trajectory(argv=None):
    from .nodes.trajectory import main

    return main(argv)


def recorder(argv=None):
    from .nodes.recorder import main

    return main(argv)


def plotter(argv=None):
    from .nodes.plotter import main

    return main(argv)


def reproduce(argv=None):
    from .cli import main

    return main(["reproduce", *(sys.argv[1:] if argv is None else argv)])


def piezo_ff(argv=None):
    from .cli import main

    return main(argv)
