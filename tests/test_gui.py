"""The posing window, headless (Agg), driven by synthesised matplotlib events.

Mouse and key events are built as matplotlib.backend_bases events and fed
through the figure's callback registry, exactly as a backend would; the
timer is replaced by calling ``tick()``.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pytest  # noqa: E402
from matplotlib.backend_bases import CloseEvent, KeyEvent, MouseEvent  # noqa: E402

from plush_opt.equilibrium import EquilibriumOptions, solve_equilibrium  # noqa: E402
from plush_opt.errors import HardwareError, SceneError  # noqa: E402
from plush_opt.gui import GuiOptions, PosingSession, add_gui_parser, cmd_gui, run_gui  # noqa: E402
from plush_opt.objective import Targets  # noqa: E402

from shipped import ROOT, body_size, built  # noqa: E402
from spec_checker import check_result  # noqa: E402


# -- synthesised events ------------------------------------------------------

def _mouse(session, name, xy, button=1):
    x, y = session.ax.transData.transform(xy)
    event = MouseEvent(name, session.fig.canvas, x, y, button=button)
    session.fig.canvas.callbacks.process(name, event)


def press(session, xy, button=1):
    _mouse(session, "button_press_event", xy, button)


def move(session, xy):
    _mouse(session, "motion_notify_event", xy, None)


def release(session, xy, button=1):
    _mouse(session, "button_release_event", xy, button)


def drag(session, start, end, steps=4):
    start, end = np.asarray(start, float), np.asarray(end, float)
    press(session, start)
    for s in np.linspace(0, 1, steps + 1)[1:]:
        move(session, start + s * (end - start))
    release(session, end)


def key(session, name):
    session.fig.canvas.callbacks.process("key_press_event",
                                         KeyEvent("key_press_event", session.fig.canvas, name))


def where_now(session, rest_point):
    """Current position of the body point at ``rest_point``."""
    mesh = session.model.mesh
    tri, beta = mesh.locate(np.reshape(rest_point, (1, 2)))
    return beta[0] @ session.x.reshape(-1, 2)[mesh.triangles[tri[0]]]


def rest_of_target(session, k):
    X = session.model.X.reshape(-1, 2)
    return session.targets.beta[k] @ X[session.targets.nodes[k]]


class Clock:
    """A clock the test moves by hand."""

    def __init__(self):
        self.t = 100.0

    def __call__(self):
        return self.t


class FakeBoard:
    """A board that records what it is told."""

    def __init__(self, fail_send=False):
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

    def stop(self):
        self.stops += 1

    def close(self):
        self.closed = True


@pytest.fixture
def make_session():
    sessions = []

    def make(name="gripper", targets=None, **kwargs):
        _, _, model, _ = built(name)
        session = PosingSession(model, targets, **kwargs)   # drawn once already (Agg)
        sessions.append(session)
        return session

    yield make
    for session in sessions:
        session.close()
    plt.close("all")


def reachable_destination(model, rest_point, c):
    """Where ``rest_point`` goes at contractions ``c`` (a target that can be met)."""
    x = solve_equilibrium(model, np.asarray(c, float), None, EquilibriumOptions(eigenvalue=False)).x
    tri, beta = model.mesh.locate(np.reshape(rest_point, (1, 2)))
    return beta[0] @ x.reshape(-1, 2)[model.mesh.triangles[tri[0]]]


TIP = (-72.0, 128.0)        # a point in the gripper's left bar, rest coordinates
TOP = (0.0, 146.0)          # near the top of the bar


# -- mode 2: drag to pose ------------------------------------------------------

def test_drag_creates_target_at_the_body_point_under_the_cursor(make_session):
    s = make_session()
    s.sliders["left"].set_val(12.0)       # deform first: the press must invert it
    start = where_now(s, TIP)
    assert np.linalg.norm(start - TIP) > 5.0
    end = start + np.array([-8.0, -20.0])
    press(s, start)
    move(s, start + 0.5 * (end - start))
    # shown during the drag, not yet a target
    assert s.targets.n_targets == 0
    preview = np.asarray(s.artists["preview"].get_data(), float).ravel()
    assert np.allclose(preview, start + 0.5 * (end - start))
    release(s, end)
    assert s.targets.n_targets == 1
    err = np.linalg.norm(rest_of_target(s, 0) - TIP)
    assert err <= 1e-6 * body_size(s.model), f"rest point off by {err} mm"
    assert np.allclose(s.targets.to[0], end, atol=1e-9)
    assert len(s.artists["preview"].get_xdata()) == 0       # the preview is gone


def test_press_off_the_body_makes_no_target(make_session):
    s = make_session()
    lo = np.array([s.ax.get_xlim()[0], s.ax.get_ylim()[0]])
    drag(s, lo + 3.0, lo + 10.0)
    assert s.targets.n_targets == 0
    assert "press on the body" in s.message


def test_objective_falls_iterate_by_iterate_one_iterate_per_tick(make_session):
    s = make_session()
    c_goal = [10.0, 0.0, 6.0]
    drag(s, where_now(s, TIP), reachable_destination(s.model, TIP, c_goal))
    objectives, sizes = [], []
    for _ in range(40):
        it = s.tick()
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


def test_sliders_follow_the_loop_without_forward_solves(make_session):
    s = make_session()
    drag(s, where_now(s, TIP), reachable_destination(s.model, TIP, [8.0, 0.0, 5.0]))
    solves = s.forward_solves
    for _ in range(8):
        s.tick()
    assert s.forward_solves == solves
    assert s.iterates_shown >= 3
    for i, name in enumerate(s.winch_names):
        assert s.sliders[name].val == s.contraction[i]
    assert s.contraction.any()


def test_move_and_right_click_remove_targets_while_the_loop_runs(make_session):
    s = make_session()
    drag(s, where_now(s, TIP), where_now(s, TIP) + [0.0, -15.0])
    drag(s, where_now(s, TOP), where_now(s, TOP) + [-20.0, 0.0])
    assert s.targets.n_targets == 2
    s.tick()
    s.tick()
    # drag target 0's marker somewhere else: same body point, new destination
    rest0 = rest_of_target(s, 0)
    old = s.targets.to[0].copy()
    drag(s, old, old + [-10.0, 5.0])
    assert s.targets.n_targets == 2
    assert np.allclose(s.targets.to[0], old + [-10.0, 5.0])
    assert np.allclose(rest_of_target(s, 0), rest0)
    s.tick()
    # right click near (a few pixels off) target 0's marker removes it
    keep = s.targets.to[1].copy()
    px = s.ax.transData.transform(s.targets.to[0]) + [3.0, -2.0]
    event = MouseEvent("button_press_event", s.fig.canvas, px[0], px[1], button=3)
    s.fig.canvas.callbacks.process("button_press_event", event)
    assert s.targets.n_targets == 1
    assert np.array_equal(s.targets.to[0], keep)
    # a right click far from any marker does nothing
    press(s, (-70.0, 0.0), button=3)
    assert s.targets.n_targets == 1
    assert s.tick() is not None or not s.running


# -- mode 3: freeze --------------------------------------------------------------

def test_frozen_winch_keeps_its_contraction_bit_for_bit(make_session):
    s = make_session()
    grip = 7.123456789012345
    s.sliders["grip"].set_val(grip)
    s.freeze_buttons["grip"].set_active(0)          # the toggle, as a click does
    assert s.frozen.tolist() == [False, False, True]
    drag(s, where_now(s, TIP), reachable_destination(s.model, TIP, [12.0, 0.0, 2.0]))
    moved = False
    for _ in range(25):
        it = s.tick()
        if it is not None:
            assert it.contraction[2] == grip and it.contraction[2].tobytes() == np.float64(grip).tobytes()
            moved = moved or it.contraction[0] != 0.0
    assert moved, "the free winches should have moved"
    assert s.contraction[2] == grip
    # releasing it lets the loop move it again
    s.freeze_buttons["grip"].set_active(0)
    assert not s.frozen[2]
    assert s.controller.frozen.tolist() == [False, False, False]


# -- mode 1: contractions ---------------------------------------------------------

def test_slider_resolves_the_pose_warm_started(make_session):
    s = make_session()
    x_rest = s.x.copy()
    s.sliders["left"].set_val(10.0)
    assert s.contraction.tolist() == [10.0, 0.0, 0.0]
    assert s.equilibrium.converged
    assert np.linalg.norm(s.x - x_rest) > 1.0
    cold = solve_equilibrium(s.model, [10.0, 0.0, 0.0])
    assert np.allclose(s.x, cold.x, atol=1e-6 * body_size(s.model))
    # the mesh on screen is that pose
    verts = s.artists["body"].get_paths()[0].vertices[:3]
    assert np.allclose(verts, s.x.reshape(-1, 2)[s.model.mesh.triangles[0]])


def test_slider_holds_a_running_loop_and_a_new_target_runs_it(make_session):
    s = make_session()
    drag(s, where_now(s, TIP), where_now(s, TIP) + [0.0, -15.0])
    assert s.running
    s.sliders["grip"].set_val(4.0)
    assert s.held and not s.running and s.tick() is None
    drag(s, where_now(s, TOP), where_now(s, TOP) + [-10.0, 0.0])
    assert s.running and s.tick() is not None


# -- keys -------------------------------------------------------------------------

def test_space_pauses_and_resumes(make_session):
    s = make_session()
    drag(s, where_now(s, TIP), reachable_destination(s.model, TIP, [10.0, 0.0, 6.0]))
    s.tick()
    s.tick()
    key(s, " ")
    assert s.paused
    n, c, x = len(s.controller.history), s.contraction.copy(), s.x.copy()
    for _ in range(5):
        assert s.tick() is None
    assert len(s.controller.history) == n
    assert np.array_equal(s.contraction, c) and np.array_equal(s.x, x)
    key(s, " ")
    assert not s.paused
    assert s.tick() is not None


def test_r_resets_to_the_scene(make_session):
    s = make_session()
    s.sliders["right"].set_val(9.0)
    drag(s, where_now(s, TIP), where_now(s, TIP) + [0.0, -10.0])
    s.tick()
    key(s, "r")
    assert s.targets.n_targets == 0
    assert np.array_equal(s.contraction, s.model.scene.contraction)
    assert [sl.val for sl in s.sliders.values()] == s.model.scene.contraction.tolist()
    assert s.controller is None


def test_s_saves_a_valid_result_and_a_png(make_session, tmp_path):
    out = tmp_path / "session" / "pose.json"
    s = make_session(options=GuiOptions(save_path=out))
    drag(s, where_now(s, TIP), reachable_destination(s.model, TIP, [10.0, 0.0, 6.0]))
    for _ in range(40):
        s.tick()
        if not s.running:
            break
    key(s, "s")
    doc = check_result(out)
    assert doc["method"] == "reparam"
    assert doc["contractions"] == dict(zip(s.winch_names, s.contraction.tolist()))
    assert doc["nodes"] == s.x.reshape(-1, 2).tolist()
    assert len(doc["model"]["targets"]) == 1
    assert np.allclose(doc["gui"]["targets_rest"][0], TIP)
    png = out.with_suffix(".png")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "saved" in s.message


def test_s_without_targets_saves_a_forward_result_in_out(make_session, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    s = make_session()
    s.sliders["grip"].set_val(5.0)
    key(s, "s")
    files = sorted((tmp_path / "out").glob("gui-*.json"))
    assert len(files) == 1 and files[0].with_suffix(".png").is_file()
    doc = json.loads(files[0].read_text())
    assert doc["method"] == "forward" and doc["converged"]
    assert doc["contractions"]["grip"] == 5.0


def test_q_quits_and_stops_the_board(make_session):
    board = FakeBoard()
    s = make_session(board=board)
    num = s.fig.number
    key(s, "q")
    assert board.stops == 1
    assert not plt.fignum_exists(num)
    assert not board.closed         # closing the link is its owner's business


# -- the board --------------------------------------------------------------------

def test_board_sends_are_rate_limited_and_the_last_pose_is_sent(make_session):
    clock, board = Clock(), FakeBoard()
    s = make_session(board=board, clock=clock, options=GuiOptions(send_rate=20.0))
    assert len(board.sent) == 1                      # the starting pose
    times = [clock.t]
    for k in range(30):                             # 30 slider moves in 0.3 s
        clock.t += 0.01
        n = len(board.sent)
        s.sliders["left"].set_val(0.5 * (k + 1))
        s.tick()
        if len(board.sent) > n:
            times.append(clock.t)
    gaps = np.diff(times)
    assert np.all(gaps >= 1 / 20 - 1e-9), gaps
    assert len(board.sent) <= 1 + 0.3 * 20 + 1
    clock.t += 0.06
    s.sliders["left"].set_val(20.0)                  # sent at once: the last send is old
    assert board.sent[-1]["left"] == 20.0
    s.sliders["left"].set_val(21.0)                  # too soon: kept, not sent
    s.tick()
    assert board.sent[-1]["left"] == 20.0
    clock.t += 0.06
    s.tick()                                         # the last pose always goes out
    assert board.sent[-1] == dict(zip(s.winch_names, s.contraction.tolist()))
    assert board.sent[-1]["left"] == 21.0
    # the loop's iterates too: rate-limited, the last one sent
    drag(s, where_now(s, TIP), where_now(s, TIP) + [5.0, -10.0])
    start = len(board.sent)
    for _ in range(60):
        clock.t += 0.01
        s.tick()
    assert len(board.sent) - start <= 0.6 * 20 + 1
    assert board.sent[-1] == dict(zip(s.winch_names, s.contraction.tolist()))
    assert s.measured == board.sent[-1]


def test_closing_the_window_stops_the_board(make_session):
    clock, board = Clock(), FakeBoard()
    s = make_session(board=board, clock=clock)
    drag(s, where_now(s, TIP), where_now(s, TIP) + [0.0, -10.0])
    s.fig.canvas.callbacks.process("close_event", CloseEvent("close_event", s.fig.canvas))
    assert board.stops == 1
    n = len(board.sent)
    clock.t += 1.0
    assert s.tick() is None
    assert len(board.sent) == n                      # nothing after the stop
    s.close()
    assert board.stops == 1                          # once


def test_board_error_stops_the_board_and_keeps_the_window(make_session):
    board = FakeBoard(fail_send=True)
    s = make_session(board=board)
    assert s.board_error is not None and "unplugged" in s.board_error
    assert board.stops == 1
    s.sliders["left"].set_val(3.0)                   # the window still works
    assert s.equilibrium.converged
    assert "ERROR" in s.status_text.get_text()


def test_emulated_board_follows_the_contractions(make_session):
    board_mod = pytest.importorskip("plush_opt.board")
    try:
        board_mod.emulator_binary()
    except HardwareError as exc:
        pytest.skip(str(exc))
    from plush_opt.gui import DriverBoard
    calibration = board_mod.load_calibration(ROOT / "hw" / "boards" / "gripper.yaml")
    _, _, model, _ = built("gripper")
    bounds = {n: (float(lo), float(hi)) for n, lo, hi in zip(model.winch_names, model.lower, model.upper)}
    speed = 4 * max(w.speed_ticks for w in calibration.winches)
    with board_mod.Emulator(winches=calibration.n_axes_required, speed=speed) as emu:
        with board_mod.Driver(emu.port, calibration, bounds=bounds) as driver:
            s = make_session(board=DriverBoard(driver), options=GuiOptions(poll_rate=50.0))
            s.sliders["left"].set_val(6.0)
            s.sliders["grip"].set_val(3.0)
            drag(s, where_now(s, TIP), reachable_destination(model, TIP, [9.0, 0.0, 4.0]))
            deadline = time.monotonic() + 10.0
            while time.monotonic() < deadline:
                s.tick()
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
                w = calibration.winch(n)
                assert abs(w.to_mm(round(true["position"][w.axis])) - c) <= 1.0 / w.ticks_per_mm
            stops = true["stops"]["command"]
            s.close()
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


def test_no_window_without_an_interactive_backend(capsys):
    # the tests run on Agg: the window cannot open, and says what to do
    assert run_gui(ROOT / "problems" / "gripper.yaml") == 2
    err = capsys.readouterr().err
    assert "cannot open a window" in err and "--screenshot" in err


def test_screenshot_command_headless(tmp_path, capsys):
    png = tmp_path / "shot.png"
    assert run_gui(ROOT / "problems" / "gripper.yaml", screenshot=png) == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    out = capsys.readouterr().out
    assert "tick" in out and "worst ms" in out


def test_importing_the_module_stays_light():
    # the command line imports it to build its parser
    code = ("import sys, plush_opt.gui; "
            "print(sorted(m for m in ('numpy', 'matplotlib', 'casadi') if m in sys.modules))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


def test_targets_of_the_problem_file_start_held(make_session):
    _, mesh, model, targets = built("gripper")
    s = make_session(targets=targets)
    assert s.held and not s.running and s.tick() is None
    key(s, " ")
    assert s.running and s.tick() is not None
    assert isinstance(s.targets, Targets) and s.targets.n_targets == 3
