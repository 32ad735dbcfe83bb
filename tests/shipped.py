"""The shipped problems, loaded, meshed and modelled once per test session."""

from __future__ import annotations

import functools
from pathlib import Path

import yaml

from plush_opt.problem import load

ROOT = Path(__file__).resolve().parent.parent
PROBLEMS = ("gripper", "hexapod", "hexapod_leg")


@functools.lru_cache(maxsize=None)
def built(name: str):
    """(scene, mesh, model, targets) of problems/<name>.yaml."""
    p = problem(name)
    return p.scene, p.mesh, p.model, p.targets


@functools.lru_cache(maxsize=None)
def problem(name: str):
    """The :class:`~plush_opt.problem.Problem` of problems/<name>.yaml."""
    return load(ROOT / "problems" / f"{name}.yaml")


def body_size(model) -> float:
    X = model.X.reshape(-1, 2)
    return float((X.max(axis=0) - X.min(axis=0)).max())


def with_max_area(source: Path, folder: Path, max_area: float, name: str) -> Path:
    """A copy of problem file ``source`` as ``folder/name`` with another
    mesh.max_area (a cheaper mesh, for the command line)."""
    doc = yaml.safe_load(Path(source).read_text())
    doc["mesh"]["max_area"] = max_area
    path = Path(folder) / name
    path.write_text(yaml.safe_dump(doc))
    return path
