"""The tutorials in docs/tutorials execute from top to bottom (nbclient), with short episodes."""

from __future__ import annotations

from pathlib import Path

import pytest

nbformat = pytest.importorskip("nbformat", reason="the dev extra installs nbformat and nbclient")
nbclient = pytest.importorskip("nbclient", reason="the dev extra installs nbformat and nbclient")

ROOT = Path(__file__).resolve().parents[2]
NOTEBOOKS = sorted((ROOT / "docs" / "tutorials").glob("*.ipynb"))


def _text(nb: object) -> str:
    out = []
    for cell in nb.cells:  # type: ignore[attr-defined]
        for o in cell.get("outputs", []):
            out.append(o.get("text", "") or str(o.get("data", {}).get("text/plain", "")))
    return "\n".join(out)


def test_there_are_two_tutorials() -> None:
    assert [p.name[:3] for p in NOTEBOOKS] == ["01_", "02_"]


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_executes(path: Path) -> None:
    nb = nbformat.read(path, as_version=4)
    nbclient.NotebookClient(nb, timeout=300, kernel_name="python3",
                            resources={"metadata": {"path": str(ROOT)}}).execute()
    text = _text(nb)
    assert "Traceback" not in text
    assert "iae_Kh" in text  # every tutorial prints KPIs it computed
