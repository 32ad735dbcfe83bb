"""Child process of test_board_signals: ``plush-opt run`` (the CLI's main,
with its signal policy) with a slow FakePlanner in place of the solver.

Usage: python cli_child.py SCRIPT LOG BOARD-ARGS...
The first forward solve takes START_DELAY s, so a signal can land while the
run starts; pose steps stream 400 iterates, 10 ms apart.
"""

import sys
import time

from fake_planner import FakePlanner  # sibling file: this script's folder is on sys.path

from plush_opt.apps import cli, planner

START_DELAY = 1.5


class SlowStartPlanner(FakePlanner):
    def __init__(self, problem):
        super().__init__(upper=[20.0, 20.0, 20.0], steps=400, delay=0.01, goal={"left": 20.0, "right": 20.0})
        self._started = False

    def forward(self, contraction):
        if not self._started:
            self._started = True
            time.sleep(START_DELAY)
        return super().forward(contraction)


def main():
    script, log_path, *board = sys.argv[1:]
    planner.ControlPlanner = SlowStartPlanner     # cmd_run imports it at call time
    return cli.main(["run", script, "--log", log_path, *board])


if __name__ == "__main__":
    sys.exit(main())
