"""The archive-exploration notebook runs top to bottom against a tiny run."""

from pathlib import Path

import nbformat
from nbclient import NotebookClient

NOTEBOOK = Path(__file__).resolve().parents[1] / "notebooks" / "explore_archive.ipynb"


def test_explore_archive_notebook_executes(full_run, tmp_path, monkeypatch):
    _execute(full_run[0], tmp_path, monkeypatch, 4)  # the session's short maze run (conftest), only read


def test_the_notebook_explores_a_dsage_run(tmp_path, monkeypatch):
    """A DSAGE archive holds layouts, not generators: drawn at the training size only."""
    from test_dsage import TINY_DSAGE

    from experiments.cli import compose_config
    from nca_qd.experiment import Experiment

    run_dir = tmp_path / "dsage"
    Experiment(compose_config("run", [*TINY_DSAGE, "qd.n_evals=40"]), run_dir).run()
    _execute(run_dir, tmp_path, monkeypatch, 3)  # the archive, elites at S, one more at S


def test_the_notebook_opens_the_shipped_archive_by_default(monkeypatch):
    """Started in notebooks/ with no run named, it explores results/warehouse_even_qd/cma_mae_a5_s0 (its
    portable snapshot: the repository ships no full checkpoint)."""
    monkeypatch.delenv("NCA_QD_RUN_DIR", raising=False)
    nb = _execute(None, NOTEBOOK.parent, monkeypatch, 4)
    assert "cma_mae on warehouse_even" in "".join(
        o.get("text", "") for o in nb.cells[1].get("outputs", []) if o.get("output_type") == "stream"
    )


def _execute(run_dir, cwd, monkeypatch, n_images):
    if run_dir is not None:
        monkeypatch.setenv("NCA_QD_RUN_DIR", str(run_dir))
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    nb = nbformat.read(NOTEBOOK, as_version=4)
    NotebookClient(
        nb, timeout=600, kernel_name="python3", resources={"metadata": {"path": str(cwd)}}
    ).execute()
    images = [
        o
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if "image/png" in o.get("data", {})
    ]
    assert len(images) >= n_images, "the notebook should draw the archive and the elites"
    errors = [
        o
        for c in nb.cells
        if c.cell_type == "code"
        for o in c.get("outputs", [])
        if o.get("output_type") == "error"
    ]
    assert not errors
    return nb
