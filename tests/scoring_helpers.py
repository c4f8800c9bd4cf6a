"""What the scoring tests share: a tiny warehouse search's settings."""

# A tiny warehouse: 9x10 storage area (9x14 with the workstation columns), 10 agents.
TINY_WAREHOUSE = [
    "domain=warehouse_even",
    "domain.size.train=[9,10]",
    "domain.size.eval=[13,14]",
    "domain.repair.n_shelves.train=20",
    "domain.repair.n_shelves.eval=40",
    "domain.n_agents.train=10",
    "domain.n_agents.eval=20",
    "domain.simulation.T=60",
    "domain.simulation.n_runs=2",
    "domain.measures.ranges=[[0,1],[0,30]]",
    "domain.measures.cells=[10,10]",
    "qd.n_emitters=2",
    "qd.batch_size=3",
    "qd.progress=false",
    # a window budget, not time: repairs (and so resumed runs) do not depend on the machine's load
    "domain.repair.improve_windows=4",
]
