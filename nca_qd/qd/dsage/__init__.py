"""DSAGE (Deep Surrogate Assisted Generation of Environments), the paper's direct-search
baseline: :mod:`~nca_qd.qd.dsage.surrogate` (the CNN), :mod:`~nca_qd.qd.dsage.tiles` (MAP-Elites
over tile layouts, downsampling) and :mod:`~nca_qd.qd.dsage.loop` (the outer loop)."""

from nca_qd.qd.dsage.loop import DSAGELoop

__all__ = ["DSAGELoop"]
