"""nca-qd: quality-diversity search over neural cellular automata that generate environments for
robots (warehouses, manufacturing floors, mazes); see README.md."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("nca-qd")
except PackageNotFoundError:  # a source tree that was not installed
    __version__ = "0+unknown"
