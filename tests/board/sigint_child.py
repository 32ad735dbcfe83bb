"""Child process of test_board_runs: a scripted run that the test interrupts.

Usage: python sigint_child.py SCRIPT PORT LOG
Runs SCRIPT on the board at PORT with a slow FakePlanner; exits 130 on
KeyboardInterrupt (after run_script has stopped the board).
"""

import logging
import sys

from fake_planner import FakePlanner  # sibling file: this script's folder is on sys.path
from plush_opt.apps.runs import run_script


def main():
    script, port, log_path = sys.argv[1:4]
    logging.basicConfig(level=logging.WARNING)
    planner = FakePlanner(upper=[20.0, 20.0, 20.0], steps=400, delay=0.01, goal={"left": 20.0, "right": 20.0})
    try:
        run_script(script, port=port, log_path=log_path, planner=planner, progress=False)
    except KeyboardInterrupt:
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
