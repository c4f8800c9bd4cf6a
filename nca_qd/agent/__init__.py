"""The learned maze agent (paper's ACCEL agent): network, PPO + ACCEL training, shipped weights.

Importing this package registers the ``learned`` maze policy kind
(:func:`nca_qd.sim.maze_agent.register_policy`); its weights are loaded on first use.
"""

from nca_qd.agent.shipped import load_agent, save_agent, shipped_policy
from nca_qd.sim.maze_agent import register_policy

register_policy("learned", shipped_policy)

__all__ = ["load_agent", "save_agent", "shipped_policy"]
