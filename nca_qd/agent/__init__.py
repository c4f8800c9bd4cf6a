"""The learned maze agent (paper's ACCEL agent): network, PPO + ACCEL training, shipped weights.

The maze domain reaches it by name: ``domain.agent.kind=learned`` is
``nca_qd.agent.shipped:shipped_policy`` in :data:`nca_qd.sim.maze_agent.POLICIES`, imported on
first use; its weights are loaded then. Nothing here registers itself by import.
"""

from nca_qd.agent.shipped import load_agent, save_agent, shipped_policy

__all__ = ["load_agent", "save_agent", "shipped_policy"]
