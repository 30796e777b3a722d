"""docs/tutorial.ipynb runs: its code cells executed in order in one namespace (no Jupyter kernel
needed), with matplotlib's Agg canvas; the notebook's own asserts are the physics checks
(momentum = impulse, ω_x = 0 to the bit without a field, ω_x reversed with B, the loop's
μ0I/2a, a sweep case equal to the same run in this process, the history's units).

The runs are shrunk in the notebook itself (15 × 15 nodes, 300 µs: its section 1 says why);
the whole notebook takes about 40 s on a busy 2-core machine with a warm kernel cache, most of
it the local Dask cluster of the sweep and the figures' PDFs.
"""

from __future__ import annotations

import json
import shutil
import tempfile
import time
from pathlib import Path

import matplotlib

NOTEBOOK = Path(__file__).resolve().parents[1] / "docs" / "tutorial.ipynb"


def _notebook() -> dict:
    return json.loads(NOTEBOOK.read_text(encoding="utf-8"))


def _code_cells(nb: dict) -> list[str]:
    return ["".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"]


def test_tutorial_is_stored_clean():
    """nbformat 4, sources as lists of lines, no outputs and no execution counts, no magics or
    shell escapes (the test runs the cells as plain Python)."""
    nb = _notebook()
    assert nb["nbformat"] == 4
    assert nb["metadata"]["kernelspec"]["language"] == "python"
    kinds = [c["cell_type"] for c in nb["cells"]]
    assert set(kinds) == {"markdown", "code"} and kinds[0] == "markdown"
    for cell in nb["cells"]:
        assert isinstance(cell["source"], list) and cell["source"]
        assert all(line.endswith("\n") for line in cell["source"][:-1])
        if cell["cell_type"] == "code":
            assert cell["execution_count"] is None and cell["outputs"] == []
            for line in cell["source"]:
                assert not line.lstrip().startswith(("%", "!")), line
    for source in _code_cells(nb):
        compile(source, str(NOTEBOOK), "exec")


def test_tutorial_runs(monkeypatch, tmp_path):
    """Every code cell in order; the notebook's asserts must hold. The notebook writes into a
    fresh tempfile.mkdtemp() folder only (checked), removed afterwards."""
    matplotlib.use("Agg", force=True)
    import matplotlib.pyplot as plt

    monkeypatch.chdir(tmp_path)  # a stray relative path would land here, not in the repo
    namespace: dict = {"__name__": "__tutorial__"}
    t0 = time.perf_counter()
    cells = []
    try:
        for k, source in enumerate(_code_cells(_notebook())):
            code = compile(source, f"{NOTEBOOK.name}, code cell {k + 1}", "exec")
            t = time.perf_counter()
            exec(code, namespace)  # noqa: S102 - the notebook is the test's input
            cells.append(f"{k + 1}: {time.perf_counter() - t:.1f} s")
    finally:
        plt.close("all")
        work = namespace.get("work")
        if isinstance(work, Path) and work.is_dir():
            assert work.resolve().is_relative_to(Path(tempfile.gettempdir()).resolve())
            shutil.rmtree(work)
    wall = time.perf_counter() - t0
    print(f"tutorial notebook executed in {wall:.1f} s (code cells {', '.join(cells)})")
    assert list(tmp_path.iterdir()) == []
