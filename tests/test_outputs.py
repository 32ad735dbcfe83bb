"""Every output file goes through the same atomic path: on a full disk a
VTK pose, a time series or a picture leaves no partial file, and the error
names the file that could not be written."""

import errno
import os
import subprocess
import sys
from types import SimpleNamespace

import matplotlib

matplotlib.use("Agg")
import numpy as np  # noqa: E402
import pytest  # noqa: E402

from plush_opt.base import files  # noqa: E402
from shipped import ROOT  # noqa: E402


@pytest.fixture(scope="module")
def gripper():
    import plush_opt
    p = plush_opt.load(ROOT / "problems" / "gripper.yaml")
    return p, p.equilibrium({"left": 10.0, "grip": 5.0})


@pytest.fixture
def full_disk(monkeypatch):
    """Every fsync fails as on a full disk."""
    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(files.os, "fsync", fsync)


def _fails_naming(path, write):
    with pytest.raises(OSError) as info:
        write()
    assert info.value.filename == str(path) and info.value.errno == errno.ENOSPC
    assert "No space left" in info.value.strerror


def test_a_vtk_pose_on_a_full_disk_leaves_nothing(tmp_path, gripper, full_disk):
    from plush_opt.apps.export import write_pose
    p, eq = gripper
    out = tmp_path / "pose.vtu"
    _fails_naming(out, lambda: write_pose(out, p.model, eq.x, eq.contraction, eq))
    assert list(tmp_path.iterdir()) == []


def test_a_vtk_series_on_a_full_disk_leaves_nothing(tmp_path, gripper, full_disk):
    from plush_opt.apps.export import write_series
    p, eq = gripper
    frames = [(0.0, eq.x, eq.contraction), (1.0, eq.x, eq.contraction)]
    _fails_naming(tmp_path / "vtk" / "run_0000.vtu", lambda: write_series(tmp_path / "vtk", "run", p.model, frames))
    assert list((tmp_path / "vtk").iterdir()) == []


def test_the_series_index_on_a_full_disk_leaves_nothing(tmp_path, gripper, monkeypatch):
    from plush_opt.apps import export
    p, eq = gripper
    monkeypatch.setattr(export, "write_pose", lambda path, *a: path)     # the frames are fine
    real = files.os.fsync

    def fsync(fd):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    monkeypatch.setattr(files.os, "fsync", fsync)
    pvd = tmp_path / "run.pvd"
    _fails_naming(pvd, lambda: export.write_series(tmp_path, "run", p.model, [(0.0, eq.x, eq.contraction)]))
    assert list(tmp_path.iterdir()) == []
    monkeypatch.setattr(files.os, "fsync", real)


@pytest.mark.parametrize("which", ["pose", "trace", "run"])
def test_a_picture_on_a_full_disk_leaves_nothing(tmp_path, gripper, full_disk, which):
    from plush_opt.apps import plot
    p, eq = gripper
    out = tmp_path / f"{which}.png"
    if which == "pose":
        write = lambda: plot.plot_pose(out, p.model, eq.x, eq.contraction)         # noqa: E731
    elif which == "trace":
        history = [SimpleNamespace(iteration=k, objective=1.0 / (k + 1), t_wall=0.1 * k) for k in range(3)]
        write = lambda: plot.plot_trace(out, history)                                 # noqa: E731
    else:
        rows = [{"t": t, "commanded": {"a": t}, "measured": {"a": t}, "step": 0, "kind": "move"}
                for t in (0.0, 1.0)]
        write = lambda: plot.plot_run_log(out, rows)                                  # noqa: E731
    _fails_naming(out, write)
    assert list(tmp_path.iterdir()) == []


def test_a_calibration_picture_on_a_full_disk_leaves_nothing(tmp_path, full_disk, monkeypatch):
    from plush_opt.apps import calibrate_plot
    monkeypatch.setattr(calibrate_plot, "_panel", lambda ax, *a: ax.plot([0, 1], [0, 1]))
    meas = SimpleNamespace(n_poses=1, seen=[np.ones(1, bool)], positions=[np.zeros((1, 2))],
                           scene=SimpleNamespace(name="s", winch_names=["a"]), contractions=[[1.0]])
    result = SimpleNamespace(before=None, after=None, fitted_poses=[True])
    _fails_naming(tmp_path / "plots" / "pose_00.png", lambda: calibrate_plot.plot_poses(tmp_path / "plots", meas, result))
    assert list((tmp_path / "plots").iterdir()) == []


def test_an_unwritable_vtk_folder_is_one_line_naming_the_file(tmp_path, gripper, full_disk, capsys):
    """The command's message names the file (in-process, so the disk can be full)."""
    from plush_opt.apps import cli
    p, _ = gripper
    code = cli.main(["solve", str(ROOT / "problems" / "gripper.yaml"), "--method", "forward",
                     "--vtk", str(tmp_path / "vtk")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert f"{tmp_path / 'vtk' / 'pose.vtu'}: cannot write: No space left on device" in err[0]
    assert list((tmp_path / "vtk").iterdir()) == []


# -- a run log in use by another run is refused ------------------------------

def test_a_run_log_in_use_is_refused_and_left_alone(tmp_path):
    import fcntl

    from plush_opt.apps.run_log import RunLog
    from plush_opt.base.errors import SceneError
    path = tmp_path / "run.jsonl"
    first = RunLog(path)
    first.write({"t": 0, "event": "start"})
    with pytest.raises(SceneError) as info:
        RunLog(path)
    assert str(path) in str(info.value) and "in use by another run" in str(info.value)
    first.write({"t": 1, "event": "end"})
    first.close()
    assert [line[:6] for line in path.read_text().splitlines()] == ['{"t":0', '{"t":1']
    with RunLog(path) as again:        # free again once the first run has ended
        again.write({"t": 0})
    assert path.read_text() == '{"t":0}\n'
    with open(path, "rb") as held:     # another process's lock, taken with flock(1) or a run
        fcntl.flock(held.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
        with pytest.raises(SceneError):
            RunLog(path)
    assert path.read_text() == '{"t":0}\n'


def test_two_runs_on_one_log_the_second_is_refused(tmp_path):
    from cli_helpers import cli, one_error_line
    log = tmp_path / "run.jsonl"
    log.write_text('{"t":0,"event":"start"}\n')
    holder = subprocess.Popen([sys.executable, "-c", "import fcntl, sys, time\n"
                               "f = open(sys.argv[1], 'rb'); fcntl.flock(f, fcntl.LOCK_EX)\n"
                               "print('held', flush=True); time.sleep(120)", str(log)],
                              stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout.readline().strip() == "held"
        p = cli("run", ROOT / "examples" / "gripper_run.yaml", "--dry-run", "--log", log, timeout=300)
        line = one_error_line(p)
        assert str(log) in line and "in use by another run" in line, line
        assert log.read_text() == '{"t":0,"event":"start"}\n'
    finally:
        holder.kill()
        holder.wait()


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="needs /dev/full")
def test_a_log_on_a_full_device_is_one_line(tmp_path):
    """The run fails writing its first line; the end line fails the same way and adds nothing."""
    from cli_helpers import cli, one_error_line
    line = one_error_line(cli("run", ROOT / "examples" / "gripper_run.yaml", "--dry-run", "--log", "/dev/full",
                              timeout=300))
    assert "/dev/full: cannot write the run log: No space left on device" in line, line
