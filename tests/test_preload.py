"""A long run reads its source once, at its start (nca_qd.preload).

The hazard it guards against happened: a maze search started at one commit imported a module of a
later commit at its last step and died there. Here, the moment the run has preloaded, the import
system is made to refuse every ``nca_qd`` module it does not hold yet, as a tree edited under the
run would (the package is installed editable, so a copied tree would not be read). The run must
still finish and draw its pictures (the step that died), importing nothing new.
"""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

from conftest import TINY_MAZE

REPO = Path(__file__).resolve().parents[1]

DRIVER = textwrap.dedent(
    """
    import sys
    from pathlib import Path

    repo, run_dir = Path(sys.argv[1]), Path(sys.argv[2])
    import nca_qd.preload as preload_module

    original = preload_module.preload


    class EditedTree:
        def find_spec(self, name, path=None, target=None):
            if name == "nca_qd" or name.startswith("nca_qd."):
                raise ImportError(f"{name}: edited after the run started")
            return None


    def preload_then_edit(package="nca_qd"):
        names = original(package)
        # Every module file of the package, found from the files, not from the code under test.
        expected = {
            ".".join(f.relative_to(repo).with_suffix("").parts).removesuffix(".__init__")
            for f in (repo / package).rglob("*.py")
        }
        missing = expected - set(sys.modules)
        print(f"preloaded {len(names)} of {len(expected)} modules; not loaded: {sorted(missing)}")
        print("metrics before preload:", (run_dir / "metrics.csv").exists())
        sys.meta_path.insert(0, EditedTree())
        print("tree edited", flush=True)
        return names


    preload_module.preload = preload_then_edit
    from experiments.run import main

    sys.exit(main(sys.argv[3:]))
    """
)


def test_a_run_reads_its_source_once_so_later_edits_cannot_reach_it(tmp_path):
    (tmp_path / "driver.py").write_text(DRIVER)
    run_dir = tmp_path / "run"
    env = {**os.environ, "JAX_PLATFORMS": "cpu", "PYTHONPATH": str(REPO)}
    args = [*TINY_MAZE, "qd.n_evals=16", "output.pictures=true", f"run_dir={run_dir}"]
    proc = subprocess.run(
        [sys.executable, str(tmp_path / "driver.py"), str(REPO), str(run_dir), *args],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=300,
        env=env,
    )
    out = proc.stdout + proc.stderr
    assert "tree edited" in proc.stdout, out  # the run called preload
    assert "metrics before preload: False" in proc.stdout, out  # ... before its first iteration
    assert "not loaded: []" in proc.stdout, out  # ... and it imported every module
    assert proc.returncode == 0, out
    assert "edited after the run started" not in out
    # The end of the run, where the lazy imports are, ran: archives, record and pictures.
    for name in ("archive_result.npz", "elites.npz", "archive_result.png", "best_eval.png"):
        assert (run_dir / name).is_file(), (name, sorted(p.name for p in run_dir.iterdir()))
