"""The counted work of a solve (plush_opt.solve.work), and a sweep whose
levels and pick do not depend on the clock."""

import types
from pathlib import Path

import numpy as np

from plush_opt.fem.model import Model
from plush_opt.io import load_scene
from plush_opt.problem import load
from plush_opt.solve import accuracy
from plush_opt.solve import work as counting
from plush_opt.solve.equilibrium import solve_equilibrium
from plush_opt.solve.work import FACTOR_S, OPERATION_S, Work, counted

ROOT = Path(__file__).resolve().parents[1]


def test_work_counts_each_factorisation_and_evaluation():
    w = Work(factored=[100, 400], hessians=2, gradients=3)
    expected = FACTOR_S * (100 ** 1.5 + 400 ** 1.5) + (14e-9 * 2 + 10e-9 * 3) * 400 + OPERATION_S * 7
    assert np.isclose(w.seconds, expected, rtol=1e-12)
    assert Work().seconds == 0.0


def test_the_same_solve_counts_the_same_work_and_the_model_is_restored():
    model = load(ROOT / "problems" / "cantilever.yaml").model
    c = model.scene.contraction
    runs = []
    for _ in range(2):
        with counted(model) as work:
            eq = solve_equilibrium(model, c)
        assert eq.converged
        runs.append(work)
    assert runs[0] == runs[1] and runs[0].seconds > 0
    assert len(runs[0].factored) >= 1 and runs[0].hessians >= 1
    # the wrappers are gone: the class's methods again
    assert "evaluate" not in vars(model) and "factor" not in vars(model.factorizer)
    assert type(model).evaluate is Model.evaluate


def test_the_sweep_solves_and_picks_the_same_levels_whatever_the_clock_says(monkeypatch):
    """Measured CPU seconds follow the machine's load; a clock that returns
    noise stands for it. Two sweeps under two such clocks solve the same
    levels in the same order and pick the same one (with measured times
    deciding, they did not)."""
    scene = load_scene(ROOT / "problems" / "hexapod_leg.yaml")

    def sweep_under(seed):
        rng = np.random.default_rng(seed)
        now = [0.0]

        def process_time():
            now[0] += rng.uniform(0.0, 5.0)
            return now[0]

        # (the levels' measured CPU seconds come from plush_opt.solve.work's clock)
        monkeypatch.setattr(counting, "time", types.SimpleNamespace(process_time=process_time))
        best, levels, report = accuracy.choose_levels(scene, 0.25)
        return [(lv.element, lv.mesh.n_nodes) for lv in levels], report["picked"], report["work_s"]

    first, second = sweep_under(1), sweep_under(2)
    assert first == second
    assert len(first[0]) >= 3


def test_a_level_solved_by_ipopt_is_priced_by_its_measured_time():
    """IPOPT's own evaluations do not go through Model.evaluate: its count
    would say next to nothing, so such a level's cost is its measured time."""
    import dataclasses
    scene = load_scene(ROOT / "problems" / "cantilever.yaml")
    res = accuracy.default_levels(scene, "P1")[0]
    points, _ = accuracy.probe_points(scene)
    cs = np.asarray(scene.contraction, dtype=np.float64)[None]
    p1 = dataclasses.replace(scene, element="P1")
    newton = accuracy._solve_level(p1, res, cs, points, None, accuracy.LEVEL_OPTIONS)
    assert newton.work is not None and newton.work > 0 and newton.cost == newton.work
    ipopt = accuracy._solve_level(p1, res, cs, points, None,
                                  dataclasses.replace(accuracy.LEVEL_OPTIONS, backend="ipopt"))
    assert ipopt.work is None and ipopt.cost == ipopt.t_solve
