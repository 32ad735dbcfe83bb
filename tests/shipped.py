"""The shipped problems, loaded, meshed and modelled once per test session."""

from __future__ import annotations

import functools
from pathlib import Path

from plush_opt.io import load_scene
from plush_opt.mesh import build_mesh
from plush_opt.model import build_model
from plush_opt.objective import Targets

ROOT = Path(__file__).resolve().parent.parent
PROBLEMS = ("gripper", "hexapod", "hexapod_leg")


@functools.lru_cache(maxsize=None)
def built(name: str):
    """(scene, mesh, model, targets) of problems/<name>.yaml."""
    scene = load_scene(ROOT / "problems" / f"{name}.yaml")
    mesh = build_mesh(scene)
    model = build_model(scene, mesh)
    return scene, mesh, model, Targets.from_mesh(mesh, scene)


def body_size(model) -> float:
    X = model.X.reshape(-1, 2)
    return float((X.max(axis=0) - X.min(axis=0)).max())
