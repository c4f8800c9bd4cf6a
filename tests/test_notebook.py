"""The archive-exploration notebook runs top to bottom against a tiny run."""

from pathlib import Path

import nbformat
from nbclient import NotebookClient

from experiments.cli import compose_config
from nca_qd.experiment import Experiment

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "explore_archive.ipynb"


def test_explore_archive_notebook_executes(tmp_path, monkeypatch):
    run_dir = tmp_path / "tiny"
    cfg = compose_config("run", ["domain=maze", "qd.n_emitters=2", "qd.batch_size=4",
                                 "qd.n_evals=16", "domain.agent.episodes=2", "qd.progress=false",
                                 "output.pictures=false"])
    Experiment(cfg, run_dir).run()
    monkeypatch.setenv("NCA_QD_RUN_DIR", str(run_dir))
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(nb, timeout=600, kernel_name="python3",
                   resources={"metadata": {"path": str(tmp_path)}}).execute()
    images = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if "image/png" in o.get("data", {})]
    assert len(images) >= 4, "the notebook should draw the archive and the elites"
    errors = [o for c in nb.cells if c.cell_type == "code" for o in c.get("outputs", [])
              if o.get("output_type") == "error"]
    assert not errors
