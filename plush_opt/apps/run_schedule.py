"""What a scripted run sends during a pose step, and a dry run's clock.

:class:`PoseDispatch` is the dispatch rule of a pose step (docs/hardware.md,
"Run scripts"): only certified poses go to the robot, and which ones
depends on the script and the planner's results alone, never on how fast
they were computed. By default a pose step sends its final pose once; with
``stream`` it sends every certified result that moves a winch, in order,
none dropped (the runner paces them at the script's rate).

:class:`PlannedClock` is the time of a dry run: what a board run would
take, with solver time left out, so that a dry run's log is a plan.
"""

from __future__ import annotations

from collections.abc import Mapping

from ..base.errors import SolverError


def certified(result: Mapping) -> bool:
    """A planner result that may go to the robot: it says it is a certified
    stable equilibrium within bounds (``"certified": true``)."""
    return result.get("certified") is True


class PoseDispatch:
    """The commands of one pose step, chosen from the planner's results as
    they come (in the order the planner yields them).

    Parameters
    ----------
    where : str
        The step, for messages (``"run.yaml: steps[2].pose"``).
    stream : bool
        Send every certified result that moves a winch, not only the final one.
    commanded : mapping
        ``{winch: mm}`` commanded before the step.
    max_time : float
        The step's ``max_time`` (s), for messages.
    """

    def __init__(self, where: str, stream: bool, commanded: Mapping[str, float], max_time: float):
        self.where, self.stream, self.max_time = where, stream, max_time
        self.results = 0            # results received so far; a command's ``iteration`` is its result's number
        self.latest: dict | None = None
        self._last = dict(commanded)

    def take(self, result: dict) -> list[tuple[int, dict]]:
        """The next planner result; the commands it adds, as ``(iteration, result)``."""
        self.results += 1
        self.latest = result
        return self._if_it_moves(result) if self.stream and certified(result) else []

    def finish(self) -> list[tuple[int, dict]]:
        """The planner is done: the commands the final result adds. Raises
        :class:`SolverError` when the final pose may not be sent: it is not
        certified, or it depends on the computer's speed (the planner
        stopped at ``max_time``, ``"time_limited": true``)."""
        final = self.latest
        if final is None:
            return []
        if not certified(final):
            raise SolverError(f"{self.where}: the planner's final pose is not a certified equilibrium "
                              f"({final.get('status')}); nothing of this step was sent" +
                              ("" if self.stream else ", the robot stays where it is"))
        if final.get("time_limited"):
            raise SolverError(f"{self.where}: the planner stopped at max_time ({self.max_time:g} s) before its "
                              "own stop rules, so its pose would depend on how fast this computer is; "
                              "raise max_time")
        return self._if_it_moves(final) if self.stream else [(self.results, final)]

    def _if_it_moves(self, result: dict) -> list[tuple[int, dict]]:
        full = {**self._last, **result.get("contraction", {})}
        if full == self._last:
            return []
        self._last = full
        return [(self.results, result)]


class PlannedClock:
    """A dry run's time (s): every winch moves at its calibrated top speed
    towards its last command, a stream's commands are one period apart and
    a hold takes its seconds; the solver's time is not counted.

    ``speeds`` is ``{winch: mm/s}``; ``at`` the contractions where the run starts.
    """

    def __init__(self, speeds: Mapping[str, float], at: Mapping[str, float]):
        self.speeds = dict(speeds)
        self.t = 0.0
        self.at = {n: float(at[n]) for n in self.speeds}
        self.target = dict(self.at)

    def command(self, contraction: Mapping[str, float]) -> None:
        """A command sent now: the winches head for it."""
        self.target.update({n: float(v) for n, v in contraction.items() if n in self.speeds})

    def wait(self, seconds: float) -> None:
        """Let ``seconds`` pass, the winches moving."""
        for n, v in self.speeds.items():
            step = v * seconds
            gap = self.target[n] - self.at[n]
            self.at[n] = self.target[n] if abs(gap) <= step else self.at[n] + (step if gap > 0 else -step)
        self.t += seconds

    def settle(self) -> None:
        """Wait until every winch has reached its command."""
        self.t += max((abs(self.target[n] - self.at[n]) / v for n, v in self.speeds.items()), default=0.0)
        self.at = dict(self.target)
