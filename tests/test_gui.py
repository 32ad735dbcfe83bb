"""The posing session and its window.

The session (plush_opt.apps.gui.session) is driven directly, without
matplotlib (one test checks that in a fresh interpreter). The window runs
headless (Agg), driven by synthesised matplotlib events: mouse and key
events are built as matplotlib.backend_bases events and fed through the
figure's callback registry, exactly as a backend would; the timer is
replaced by calling ``tick()``. Nothing here measures wall time.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import textwrap
import time

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.backend_bases import CloseEvent, KeyEvent, MouseEvent  # noqa: E402

from plush_opt.apps.gui import GuiOptions, add_gui_parser, cmd_gui, run_gui  # noqa: E402
from plush_opt.apps.gui.session import PosingSession  # noqa: E402
from plush_opt.apps.gui.view import PosingWindow  # noqa: E402
from plush_opt.solve.equilibrium import EquilibriumOptions, solve_equilibrium  # noqa: E402
from plush_opt.base.errors import HardwareError, SceneError  # noqa: E402
from plush_opt.fem.objective import Targets  # noqa: E402
from plush_opt.problem import Problem  # noqa: E402

from shipped import ROOT, body_size, built  # noqa: E402
from spec_checker import check_result  # noqa: E402


# -- synthesised events ------------------------------------------------------

def _mouse(w, name, xy, button=1):
    x, y = w.ax.transData.transform(xy)
    event = MouseEvent(name, w.fig.canvas, x, y, button=button)
    w.fig.canvas.callbacks.process(name, event)


def press(w, xy, button=1):
    _mouse(w, "button_press_event", xy, button)


def move(w, xy):
    _mouse(w, "motion_notify_event", xy, None)


def release(w, xy, button=1):
    _mouse(w, "button_release_event", xy, button)


def drag(w, start, end, steps=4):
    start, end = np.asarray(start, float), np.asarray(end, float)
    press(w, start)
    for s in np.linspace(0, 1, steps + 1)[1:]:
        move(w, start + s * (end - start))
    release(w, end)


def key(w, name):
    w.fig.canvas.callbacks.process("key_press_event", KeyEvent("key_press_event", w.fig.canvas, name))


def where_now(s, rest_point):
    """Current position of the body point at ``rest_point`` (s: a session)."""
    mesh = s.model.mesh
    tri, beta = mesh.locate(np.reshape(rest_point, (1, 2)))
    return beta[0] @ s.x.reshape(-1, 2)[mesh.triangles[tri[0]]]


def rest_of_target(s, k):
    X = s.model.X.reshape(-1, 2)
    return s.targets.beta[k] @ X[s.targets.nodes[k]]


class Clock:
    """A clock the test moves by hand."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


class FakeBoard:
    """A :class:`~plush_opt.board.link.BoardLink` that records what it is told."""

    def __init__(self, winch_names=("left", "right", "grip"), fail_send=False):
        self.winch_names = tuple(winch_names)
        self.sent = []
        self.stops = 0
        self.closed = False
        self.fail_send = fail_send

    def send(self, contraction):
        if self.fail_send:
            raise HardwareError("board unplugged")
        self.sent.append(dict(contraction))

    def positions(self):
        return dict(self.sent[-1]) if self.sent else None

    def moving(self):
        return False

    def stop(self):
        self.stops += 1

    def close(self):
        self.closed = True


def problem(name="gripper", targets=None):
    """The shipped problem, built once per test session, with these targets
    (default none)."""
    scene, mesh, model, _ = built(name)
    return Problem(scene, mesh, model, Targets.empty() if targets is None else targets)


@pytest.fixture
def make_window():
    windows = []

    def make(name="gripper", targets=None, board=None, options=None, clock=time.monotonic):
        session = PosingSession(problem(name, targets), board, options, clock=clock)
        w = PosingWindow(session)   # drawn once already (Agg)
        windows.append(w)
        return w, session

    yield make
    for w in windows:
        w.close()
    plt.close("all")


def reachable_destination(model, rest_point, c):
    """Where ``rest_point`` goes at contractions ``c`` (a target that can be met)."""
    x = solve_equilibrium(model, np.asarray(c, float), None, EquilibriumOptions(eigenvalue=False)).x
    tri, beta = model.mesh.locate(np.reshape(rest_point, (1, 2)))
    return beta[0] @ x.reshape(-1, 2)[model.mesh.triangles[tri[0]]]


TIP = (-72.0, 128.0)        # a point in the gripper's left bar, rest coordinates
TOP = (0.0, 146.0)          # near the top of the bar


# -- the session alone, without matplotlib ---------------------------------------

SESSION_SCRIPT = textwrap.dedent("""
    import json, sys
    import numpy as np
    from plush_opt.apps.gui import GuiOptions
    from plush_opt.apps.gui.session import PosingSession
    from plush_opt.problem import load

    class Clock:
        t = 100.0
        def __call__(self):
            return self.t

    class Board:
        winch_names = ("left", "right", "grip")
        def __init__(self):
            self.sent, self.stops = [], 0
        def send(self, c):
            self.sent.append(dict(c))
        def positions(self):
            return dict(self.sent[-1]) if self.sent else None
        def moving(self):
            return False
        def stop(self):
            self.stops += 1
        def close(self):
            pass

    problem = load(sys.argv[1])
    clock, board = Clock(), Board()
    s = PosingSession(problem.with_targets(problem.targets.empty()), board,
                      GuiOptions(send_rate=20.0, save_path=sys.argv[2]), clock=clock)
    out = {"start_sends": len(board.sent), "held_at_start": s.held}
    s.set_contraction("grip", 4.0)
    s.set_frozen("grip", True)
    grip = s.contraction[2]
    rt, rb = problem.mesh.locate(np.array([[-72.0, 128.0]]))     # a point of the left bar
    here = rb[0] @ s.x.reshape(-1, 2)[problem.mesh.triangles[rt[0]]]
    tri, beta = s.locate(here)
    out["located"] = bool(tri == rt[0] and np.allclose(beta, rb[0]))
    k = s.add_target(tri, beta, here + (-8.0, -5.0))
    clock.t += 1.0
    sizes, objectives, shown = [], [], 0
    for _ in range(60):
        clock.t += 0.01
        it = s.tick()
        if it is not None:
            shown += 1
            objectives.append(it.objective)
            out.setdefault("grip_kept", True)
            out["grip_kept"] &= it.contraction[2].tobytes() == grip.tobytes()
        sizes.append(len(s.controller.history))
        if not s.running:
            break
    clock.t += 1.0
    s.tick()
    out.update(target=k, shown=shown, state=s.state, steps=[b - a for a, b in zip(sizes, sizes[1:])],
               first=objectives[0], last=objectives[-1],
               last_sent=board.sent[-1] == s.contraction_by_name, sends=len(board.sent))
    s.move_target(0, here + (-6.0, -5.0))
    out["running_after_move"] = s.running
    out["saved"] = str(s.save())
    s.remove_target(0)
    s.reset()
    out["after_reset"] = [s.targets.n_targets, s.contraction.tolist(), bool(s.frozen[2])]
    s.shutdown()
    s.shutdown()
    out["stops"] = board.stops
    out["matplotlib"] = sorted(m for m in sys.modules if m.split(".")[0] == "matplotlib")
    print(json.dumps(out))
""")


@pytest.mark.slow
def test_session_runs_without_matplotlib(tmp_path):
    out = subprocess.run([sys.executable, "-c", SESSION_SCRIPT, str(ROOT / "problems" / "gripper.yaml"),
                          str(tmp_path / "pose.json")], capture_output=True, text=True, cwd=tmp_path)
    assert out.returncode == 0, out.stderr
    r = json.loads(out.stdout)
    assert r["matplotlib"] == []
    assert r["start_sends"] == 1 and not r["held_at_start"] and r["located"]
    assert r["target"] == 0 and r["shown"] >= 3 and r["state"] == "stopped"
    assert all(step <= 1 for step in r["steps"])          # one iterate per tick at most
    assert r["grip_kept"] and r["last"] < r["first"]
    assert r["last_sent"] and r["sends"] <= 1 + 1 + (0.6 + 2.0) * 20 + 1
    assert r["running_after_move"]
    doc = check_result(r["saved"])
    assert doc["method"] == "reparam" and doc["gui"]["frozen"] == ["grip"]
    assert doc["min_hessian_eigenvalue"] is not None and doc["min_hessian_eigenvalue"] > 0
    assert r["after_reset"] == [0, [0.0, 0.0, 0.0], True]
    assert r["stops"] == 1


def test_board_pacer_sends_the_latest_pose_at_a_bounded_rate():
    from plush_opt.apps.gui.pacing import BoardPacer
    clock, board = Clock(), FakeBoard()
    pacer = BoardPacer(board, clock, send_rate=10.0, poll_rate=2.0)
    pacer.queue({"left": 1.0})
    assert pacer.service() is None and board.sent == [{"left": 1.0}]
    for v in (2.0, 3.0, 4.0):                  # too soon: the latest is kept
        clock.t += 0.02
        pacer.queue({"left": v})
        pacer.service()
    assert board.sent == [{"left": 1.0}] and pacer.pending == {"left": 4.0}
    clock.t += 0.05
    pacer.service()
    assert board.sent[-1] == {"left": 4.0} and pacer.pending is None and pacer.sends == 2
    assert pacer.measured == {"left": 1.0}     # read at the first service only (2 Hz)
    clock.t += 0.5
    pacer.service()
    assert pacer.measured == {"left": 4.0} and pacer.lag({"left": 4.5}) == pytest.approx(0.5)
    pacer.stop()
    pacer.stop()
    pacer.queue({"left": 5.0})
    clock.t += 1.0
    pacer.service()
    assert board.stops == 1 and board.sent[-1] == {"left": 4.0}


def test_board_pacer_stops_the_board_on_an_error():
    from plush_opt.apps.gui.pacing import BoardPacer
    clock, board = Clock(), FakeBoard(fail_send=True)
    pacer = BoardPacer(board, clock, send_rate=10.0, poll_rate=2.0)
    pacer.queue({"left": 1.0})
    assert "unplugged" in pacer.service()
    assert board.stops == 1 and pacer.state()["error"] == "board unplugged"
    clock.t += 1.0
    assert pacer.service() is None and pacer.sends == 0


def test_saving_computes_the_eigenvalue_once_and_only_when_missing():
    s = PosingSession(problem())
    assert s.equilibrium.min_eigenvalue is None        # forward solves skip it
    checked = s.certified()
    assert checked.min_eigenvalue is not None and checked is s.certified()
    assert np.array_equal(checked.x, s.x)
    s.set_contraction("grip", 3.0)
    assert s.certified() is not checked                 # a new pose: computed again
    with_eig = PosingSession(problem(), options=GuiOptions(equilibrium=EquilibriumOptions()))
    assert with_eig.certified() is with_eig.equilibrium  # already there: no second solve


def test_unknown_winch_names_are_refused():
    s = PosingSession(problem())
    with pytest.raises(KeyError, match="no winch 'thumb'; winches: left, right, grip"):
        s.set_contraction("thumb", 1.0)


# -- mode 2: drag to pose ------------------------------------------------------

@pytest.mark.slow
def test_drag_creates_target_at_the_body_point_under_the_cursor(make_window):
    w, s = make_window()
    w.sliders["left"].set_val(12.0)       # deform first: the press must invert it
    start = where_now(s, TIP)
    assert np.linalg.norm(start - TIP) > 5.0
    end = start + np.array([-8.0, -20.0])
    press(w, start)
    move(w, start + 0.5 * (end - start))
    # shown during the drag, not yet a target
    assert s.targets.n_targets == 0
    preview = np.asarray(w.artists["preview"].get_data(), float).ravel()
    assert np.allclose(preview, start + 0.5 * (end - start))
    release(w, end)
    assert s.targets.n_targets == 1
    err = np.linalg.norm(rest_of_target(s, 0) - TIP)
    assert err <= 1e-6 * body_size(s.model), f"rest point off by {err} mm"
    assert np.allclose(s.targets.to[0], end, atol=1e-9)
    assert len(w.artists["preview"].get_xdata()) == 0       # the preview is gone


def test_press_off_the_body_makes_no_target(make_window):
    w, s = make_window()
    lo = np.array([w.ax.get_xlim()[0], w.ax.get_ylim()[0]])
    drag(w, lo + 3.0, lo + 10.0)
    assert s.targets.n_targets == 0
    assert "press on the body" in s.message


@pytest.mark.slow
def test_objective_falls_iterate_by_iterate_one_iterate_per_tick(make_window):
    w, s = make_window()
    c_goal = [10.0, 0.0, 6.0]
    drag(w, where_now(s, TIP), reachable_destination(s.model, TIP, c_goal))
    objectives, sizes = [], []
    for _ in range(40):
        it = w.tick()
        sizes.append(len(s.controller.history))
        if it is not None:
            objectives.append(it.objective)
            assert np.array_equal(s.x, it.x)          # the mesh follows the iterate
        if not s.running:
            break
    # bounded work per tick: never more than one iterate
    assert all(b - a <= 1 for a, b in zip(sizes, sizes[1:]))
    assert len(objectives) >= 3
    assert all(b <= a for a, b in zip(objectives[1:], objectives[2:]))
    assert objectives[-1] < 1e-3 * objectives[0], objectives


@pytest.mark.slow
def test_sliders_follow_the_loop_without_forward_solves(make_window):
    w, s = make_window()
    drag(w, where_now(s, TIP), reachable_destination(s.model, TIP, [8.0, 0.0, 5.0]))
    solves = s.forward_solves
    for _ in range(8):
        w.tick()
    assert s.forward_solves == solves
    assert s.iterates_shown >= 3
    for i, name in enumerate(s.winch_names):
        assert w.sliders[name].val == s.contraction[i]
    assert s.contraction.any()


@pytest.mark.slow
def test_move_and_right_click_remove_targets_while_the_loop_runs(make_window):
    w, s = make_window()
    drag(w, where_now(s, TIP), where_now(s, TIP) + [0.0, -15.0])
    drag(w, where_now(s, TOP), where_now(s, TOP) + [-20.0, 0.0])
    assert s.targets.n_targets == 2
    w.tick()
    w.tick()
    # drag target 0's marker somewhere else: same body point, new destination
    rest0 = rest_of_target(s, 0)
    old = s.targets.to[0].copy()
    drag(w, old, old + [-10.0, 5.0])
    assert s.targets.n_targets == 2
    assert np.allclose(s.targets.to[0], old + [-10.0, 5.0])
    assert np.allclose(rest_of_target(s, 0), rest0)
    w.tick()
    # right click near (a few pixels off) target 0's marker removes it
    keep = s.targets.to[1].copy()
    px = w.ax.transData.transform(s.targets.to[0]) + [3.0, -2.0]
    event = MouseEvent("button_press_event", w.fig.canvas, px[0], px[1], button=3)
    w.fig.canvas.callbacks.process("button_press_event", event)
    assert s.targets.n_targets == 1
    assert np.array_equal(s.targets.to[0], keep)
    # a right click far from any marker does nothing
    press(w, (-70.0, 0.0), button=3)
    assert s.targets.n_targets == 1
    assert w.tick() is not None or not s.running


# -- mode 3: freeze --------------------------------------------------------------

@pytest.mark.slow
def test_frozen_winch_keeps_its_contraction_bit_for_bit(make_window):
    w, s = make_window()
    grip = 7.123456789012345
    w.sliders["grip"].set_val(grip)
    w.freeze_buttons["grip"].set_active(0)          # the toggle, as a click does
    assert s.frozen.tolist() == [False, False, True]
    drag(w, where_now(s, TIP), reachable_destination(s.model, TIP, [12.0, 0.0, 2.0]))
    moved = False
    for _ in range(25):
        it = w.tick()
        if it is not None:
            assert it.contraction[2] == grip and it.contraction[2].tobytes() == np.float64(grip).tobytes()
            moved = moved or it.contraction[0] != 0.0
    assert moved, "the free winches should have moved"
    assert s.contraction[2] == grip
    # releasing it lets the loop move it again
    w.freeze_buttons["grip"].set_active(0)
    assert not s.frozen[2]
    assert s.controller.frozen.tolist() == [False, False, False]


# -- mode 1: contractions ---------------------------------------------------------

@pytest.mark.slow
def test_slider_resolves_the_pose_warm_started(make_window):
    w, s = make_window()
    x_rest = s.x.copy()
    w.sliders["left"].set_val(10.0)
    assert s.contraction.tolist() == [10.0, 0.0, 0.0]
    assert s.equilibrium.converged
    assert np.linalg.norm(s.x - x_rest) > 1.0
    cold = solve_equilibrium(s.model, [10.0, 0.0, 0.0])
    assert np.allclose(s.x, cold.x, atol=1e-6 * body_size(s.model))
    # the mesh on screen is that pose
    verts = w.artists["body"].get_paths()[0].vertices[:3]
    assert np.allclose(verts, s.x.reshape(-1, 2)[s.model.mesh.triangles[0]])


@pytest.mark.slow
def test_slider_holds_a_running_loop_and_a_new_target_runs_it(make_window):
    w, s = make_window()
    drag(w, where_now(s, TIP), where_now(s, TIP) + [0.0, -15.0])
    assert s.running
    w.sliders["grip"].set_val(4.0)
    assert s.held and not s.running and w.tick() is None
    drag(w, where_now(s, TOP), where_now(s, TOP) + [-10.0, 0.0])
    assert s.running and w.tick() is not None


# -- keys -------------------------------------------------------------------------

@pytest.mark.slow
def test_space_pauses_and_resumes(make_window):
    w, s = make_window()
    drag(w, where_now(s, TIP), reachable_destination(s.model, TIP, [10.0, 0.0, 6.0]))
    w.tick()
    w.tick()
    key(w, " ")
    assert s.paused
    n, c, x = len(s.controller.history), s.contraction.copy(), s.x.copy()
    for _ in range(5):
        assert w.tick() is None
    assert len(s.controller.history) == n
    assert np.array_equal(s.contraction, c) and np.array_equal(s.x, x)
    key(w, " ")
    assert not s.paused
    assert w.tick() is not None


@pytest.mark.slow
def test_r_resets_to_the_scene(make_window):
    w, s = make_window()
    w.sliders["right"].set_val(9.0)
    drag(w, where_now(s, TIP), where_now(s, TIP) + [0.0, -10.0])
    w.tick()
    key(w, "r")
    assert s.targets.n_targets == 0
    assert np.array_equal(s.contraction, s.model.scene.contraction)
    assert [sl.val for sl in w.sliders.values()] == s.model.scene.contraction.tolist()
    assert s.controller is None


@pytest.mark.slow
def test_s_saves_a_valid_result_and_a_png(make_window, tmp_path):
    out = tmp_path / "session" / "pose.json"
    w, s = make_window(options=GuiOptions(save_path=out))
    drag(w, where_now(s, TIP), reachable_destination(s.model, TIP, [10.0, 0.0, 6.0]))
    for _ in range(40):
        w.tick()
        if not s.running:
            break
    key(w, "s")
    doc = check_result(out)
    assert doc["method"] == "reparam"
    assert doc["contractions"] == dict(zip(s.winch_names, s.contraction.tolist()))
    assert doc["nodes"] == s.x.reshape(-1, 2).tolist()
    assert len(doc["model"]["targets"]) == 1
    assert np.allclose(doc["gui"]["targets_rest"][0], TIP)
    png = out.with_suffix(".png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "saved" in s.message


@pytest.mark.slow
def test_s_without_targets_saves_a_forward_result_in_out(make_window, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    w, s = make_window()
    w.sliders["grip"].set_val(5.0)
    key(w, "s")
    files = sorted((tmp_path / "out").glob("gui-*.json"))
    assert len(files) == 1 and files[0].with_suffix(".png").is_file()
    doc = json.loads(files[0].read_text())
    assert doc["method"] == "forward" and doc["converged"]
    assert doc["contractions"]["grip"] == 5.0


def test_q_quits_and_stops_the_board(make_window):
    board = FakeBoard()
    w, s = make_window(board=board)
    num = w.fig.number
    key(w, "q")
    assert board.stops == 1
    assert not plt.fignum_exists(num)
    assert not board.closed         # closing the link is its owner's business


# -- the board --------------------------------------------------------------------

@pytest.mark.slow
def test_board_sends_are_rate_limited_and_the_last_pose_is_sent(make_window):
    clock, board = Clock(), FakeBoard()
    w, s = make_window(board=board, clock=clock, options=GuiOptions(send_rate=20.0))
    assert len(board.sent) == 1                      # the starting pose
    times = [clock.t]
    for k in range(30):                             # 30 slider moves in 0.3 s
        clock.t += 0.01
        n = len(board.sent)
        w.sliders["left"].set_val(0.5 * (k + 1))
        w.tick()
        if len(board.sent) > n:
            times.append(clock.t)
    gaps = np.diff(times)
    assert np.all(gaps >= 1 / 20 - 1e-9), gaps
    assert len(board.sent) <= 1 + 0.3 * 20 + 1
    clock.t += 0.06
    w.sliders["left"].set_val(20.0)                  # sent at once: the last send is old
    assert board.sent[-1]["left"] == 20.0
    w.sliders["left"].set_val(21.0)                  # too soon: kept, not sent
    w.tick()
    assert board.sent[-1]["left"] == 20.0
    clock.t += 0.06
    w.tick()                                         # the last pose always goes out
    assert board.sent[-1] == dict(zip(s.winch_names, s.contraction.tolist()))
    assert board.sent[-1]["left"] == 21.0
    # the loop's iterates too: rate-limited, the last one sent
    drag(w, where_now(s, TIP), where_now(s, TIP) + [5.0, -10.0])
    start = len(board.sent)
    for _ in range(60):
        clock.t += 0.01
        w.tick()
    assert len(board.sent) - start <= 0.6 * 20 + 1
    assert board.sent[-1] == dict(zip(s.winch_names, s.contraction.tolist()))
    assert s.measured == board.sent[-1]


@pytest.mark.slow
def test_closing_the_window_stops_the_board(make_window):
    clock, board = Clock(), FakeBoard()
    w, s = make_window(board=board, clock=clock)
    drag(w, where_now(s, TIP), where_now(s, TIP) + [0.0, -10.0])
    w.fig.canvas.callbacks.process("close_event", CloseEvent("close_event", w.fig.canvas))
    assert board.stops == 1
    n = len(board.sent)
    clock.t += 1.0
    assert w.tick() is None
    assert len(board.sent) == n                      # nothing after the stop
    w.close()
    assert board.stops == 1                          # once


@pytest.mark.slow
def test_board_error_stops_the_board_and_keeps_the_window(make_window):
    board = FakeBoard(fail_send=True)
    w, s = make_window(board=board)
    assert s.board_error is not None and "unplugged" in s.board_error
    assert board.stops == 1
    w.sliders["left"].set_val(3.0)                   # the window still works
    assert s.equilibrium.converged
    assert "ERROR" in w.status_text.get_text()


class DriverLink:
    """A :class:`~plush_opt.board.link.BoardLink` over an open Driver: a
    stand-in for what ``plush_opt.board.open_board`` returns, so that this
    test can also read the emulator's true state."""

    def __init__(self, driver):
        self.driver = driver
        self.winch_names = tuple(driver.calibration.winch_names)

    def send(self, contraction):
        self.driver.set_contractions(contraction)

    def positions(self):
        return self.driver.read_positions()

    def moving(self):
        return False

    def stop(self):
        self.driver.stop()

    def close(self):
        self.driver.close()


@pytest.mark.slow
def test_emulated_board_follows_the_contractions(make_window):
    board_mod = pytest.importorskip("plush_opt.board")
    try:
        board_mod.emulator_binary()
    except HardwareError as exc:
        pytest.skip(str(exc))
    calibration = board_mod.load_calibration(ROOT / "hw" / "boards" / "gripper.yaml")
    _, _, model, _ = built("gripper")
    bounds = {n: (float(lo), float(hi)) for n, lo, hi in zip(model.winch_names, model.lower, model.upper)}
    speed = 4 * max(wc.speed_ticks for wc in calibration.winches)
    with board_mod.Emulator(winches=calibration.n_axes_required, speed=speed) as emu:
        with board_mod.Driver(emu.port, calibration, bounds=bounds) as driver:
            w, s = make_window(board=DriverLink(driver), options=GuiOptions(poll_rate=50.0))
            w.sliders["left"].set_val(6.0)
            w.sliders["grip"].set_val(3.0)
            drag(w, where_now(s, TIP), reachable_destination(model, TIP, [9.0, 0.0, 4.0]))
            for _ in range(500):          # ticks, each giving the emulated winches 20 ms to move
                w.tick()
                want = dict(zip(s.winch_names, s.contraction.tolist()))
                if not s.running and s.measured is not None and all(
                        abs(s.measured[n] - want[n]) <= 1.0 / calibration.winch(n).ticks_per_mm
                        for n in want):
                    break
                time.sleep(0.02)
            else:
                pytest.fail(f"board at {s.measured}, contractions {want}")
            assert s.iterates_shown >= 2 and s.sends >= 3
            true = emu.read_state()
            for n, c in want.items():
                wc = calibration.winch(n)
                assert abs(wc.to_mm(round(true["position"][wc.axis])) - c) <= 1.0 / wc.ticks_per_mm
            stops = true["stops"]["command"]
            w.close()
            assert emu.read_state()["stops"]["command"] > stops


# -- command line -------------------------------------------------------------------

def test_gui_parser():
    parser = argparse.ArgumentParser()
    add_gui_parser(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["gui", "problems/gripper.yaml", "--emulator", "--out", "a.json"])
    assert args.func is cmd_gui and args.emulator and args.port is None
    assert str(args.out) == "a.json"
    with pytest.raises(SystemExit):
        parser.parse_args(["gui", "p.yaml", "--emulator", "--port", "/dev/ttyACM0"])
    with pytest.raises(SystemExit):
        parser.parse_args(["gui", "p.yaml", "--send-rate", "0"])


def test_no_scripted_session_on_a_real_board():
    with pytest.raises(SceneError, match="not on a real board"):
        run_gui(ROOT / "problems" / "gripper.yaml", port="/dev/ttyACM0", timing=True)


def test_no_window_without_an_interactive_backend():
    # the tests run on Agg: the window cannot open, and says what to do
    with pytest.raises(SceneError, match="cannot open a window.*--screenshot"):
        run_gui(ROOT / "problems" / "gripper.yaml")


@pytest.mark.slow
def test_command_line_says_so_with_status_2(tmp_path):
    import os
    env = dict(os.environ, MPLBACKEND="Agg")
    out = subprocess.run([sys.executable, "-m", "plush_opt", "gui", str(ROOT / "problems" / "gripper.yaml")],
                         capture_output=True, text=True, env=env, cwd=tmp_path)
    assert out.returncode == 2, out.stderr
    assert out.stderr.startswith("plush-opt: error: matplotlib backend") and "Traceback" not in out.stderr


@pytest.mark.slow
def test_screenshot_command_headless(tmp_path, capsys):
    png = tmp_path / "shot.png"
    assert run_gui(ROOT / "problems" / "gripper.yaml", screenshot=png) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = capsys.readouterr().out
    assert "tick" in out and "worst ms" in out


def test_importing_the_module_stays_light():
    # the command line imports it to build its parser
    code = ("import sys, plush_opt.apps.gui; "
            "print(sorted(m for m in ('numpy', 'matplotlib', 'casadi') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.slow
def test_targets_of_the_problem_file_start_held(make_window):
    _, mesh, model, targets = built("gripper")
    w, s = make_window(targets=targets)
    assert s.held and not s.running and w.tick() is None
    key(w, " ")
    assert s.running and w.tick() is not None
    assert isinstance(s.targets, Targets) and s.targets.n_targets == 3


# -- contact -------------------------------------------------------------------

def test_a_contact_scene_poses_live_floor_and_forces_drawn_dragging_while_touching(make_window):
    w, s = make_window("hexapod_stand")
    forces = w.artists["contact_forces"]
    assert len(forces.get_segments()) > 0                 # lying on the floor: it pushes
    corner = np.array([40.0, 30.5])
    w.sliders["a"].set_val(10.0)
    w.sliders["b"].set_val(10.0)
    risen = where_now(s, corner)
    assert risen[1] > 35.0 and s.equilibrium.converged
    drag(w, risen, risen + np.array([0.0, 5.0]))         # ask the body up: the legs push the floor
    for _ in range(30):
        w.tick()
        if not s.running:
            break
    assert where_now(s, corner)[1] > risen[1]
    assert s.model.contact.admissible(s.x)
    segs = forces.get_segments()
    assert len(segs) > 0 and all(np.all(np.isfinite(seg)) for seg in segs)
