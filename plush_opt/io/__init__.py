"""Reading the files of plush_opt: problem files, run scripts and (through
:mod:`plush_opt.board.board_file`) board calibrations.

One guarded YAML reader (:func:`read_yaml`) and one :class:`Checker`
serve every file kind, so every bad file gets the same kind of one-line
error: ``FILE: key.path[3].sub: message``.
"""

from .checker import Checker
from .problem_file import load_scene, scene_from_dict
from .run_script import load_run_script
from .yaml_reader import read_yaml

__all__ = ["Checker", "load_run_script", "load_scene", "read_yaml", "scene_from_dict"]
