"""The one thing pyproject.toml cannot say: the shipped problems, run
scripts, board files and board emulator source travel in the wheel as
package data, under plush_opt/data/ with the source tree's layout
(plush_opt/base/data_files.py finds them there, or in the source tree)."""

from setuptools import find_packages, setup

# plush_opt/data/<folder> <- <folder> of the source tree
DATA = {
    "plush_opt.data.problems": "problems",
    "plush_opt.data.examples": "examples",
    "plush_opt.data.hw": "hw",
}
DATA_FILES = {
    "plush_opt.data.problems": ["*.yaml", "*/*.yaml", "*/*/*.yaml"],
    "plush_opt.data.examples": ["*.yaml", "*.py"],
    # what hw/Makefile's emulator target compiles, and the board files
    "plush_opt.data.hw": ["boards/*.yaml", "emulator/main.cpp", "emulator/README.md",
                          "firmware/plush_winch/protocol_core.cpp", "firmware/plush_winch/protocol_core.h",
                          "PROTOCOL.md"],
}

setup(
    packages=find_packages(include=["plush_opt", "plush_opt.*"]) + list(DATA),
    package_dir=DATA,
    package_data=DATA_FILES,
    # the data folders are not Python packages: no __init__.py, nothing to import
    include_package_data=False,
)
