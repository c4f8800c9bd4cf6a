"""nca-qd: quality-diversity search over neural cellular automata that generate environments for
robots (warehouses, manufacturing floors, mazes); see README.md."""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("nca-qd")
except PackageNotFoundError:  # a source tree that was not installed
    __version__ = "0+unknown"


def __getattr__(name: str):
    """``nca_qd.load_generator`` (:mod:`nca_qd.api`), imported on first use: ``import nca_qd``
    stays light (no JAX) for tools that only read files or ``__version__``."""
    if name == "load_generator":
        from nca_qd.api import load_generator

        return load_generator
    raise AttributeError(f"module 'nca_qd' has no attribute {name!r}")
