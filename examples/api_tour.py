"""The Python API in four calls (docs/api.md); tests/test_api.py runs it.

    python examples/api_tour.py [OUT.json]
"""

import sys
from pathlib import Path

import plush_opt

ROOT = Path(__file__).resolve().parents[1]


def main(out: str = "r.json") -> plush_opt.ControlResult:
    p = plush_opt.load(ROOT / "problems" / "gripper.yaml")
    print(p)

    # the pose at given contractions (winches not named keep the file's values)
    eq = p.equilibrium({"left": 10.0})
    print(f"forward: converged={eq.converged} ({eq.status}), energy {eq.energy:.6g}, "
          f"{eq.iterations} Newton iterations")

    # contractions that bring the body to the file's targets
    result = p.control(method="reparam")
    print(f"control: {result.reason} ({result.status})")
    print("contractions: " + ", ".join(f"{n}={v:.3f}" for n, v in result.contractions.items()))
    print(f"objective {result.objective:.6g}; {result.stats.iterations} iterates, "
          f"{result.stats.equilibrium_solves} equilibrium solves")

    result.save(out)
    print(f"wrote {out}")
    return result


if __name__ == "__main__":
    main(*sys.argv[1:])
