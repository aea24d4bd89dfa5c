"""CI's Colab leg (.ci/run, leg 2): a chapter opened by itself, run from its own first cell as Colab would run it.

    python .ci/colab_cell.py pretend-colab IPYTHONDIR   # kernels started with this IPYTHONDIR see Colab's marker
    python .ci/colab_cell.py run NOTEBOOK               # run it in its folder; print what its first cell printed

The first cell (vdtutorial/course/colab.py, the README's Colab cell) acts only where ``google.colab`` is loaded, as
Colab's kernel loads it at start; an IPython start-up file stands in for that, and nothing else of Colab is faked.
"""

import sys
from pathlib import Path

MARKER = (
    "import sys, types  # Colab's kernel has google.colab loaded; a stand-in module marks this one as such\n"
    "sys.modules.setdefault('google.colab', types.ModuleType('google.colab'))\n"
)


def pretend_colab(ipython_dir: str) -> None:
    startup = Path(ipython_dir) / "profile_default" / "startup"
    startup.mkdir(parents=True, exist_ok=True)
    (startup / "00-google-colab.py").write_text(MARKER)


def run(notebook: str) -> None:
    import nbclient
    import nbformat

    path = Path(notebook).resolve()
    book = nbformat.read(path, as_version=4)
    client = nbclient.NotebookClient(
        book, timeout=None, kernel_name="python3", resources={"metadata": {"path": str(path.parent)}}
    )
    try:
        client.execute()
    finally:
        first = next(cell for cell in book.cells if cell.cell_type == "code")
        for output in first.get("outputs", []):
            print(output.get("text", "") or output.get("evalue", ""), end="")
    print(f"ran {path.name}: {sum(cell.cell_type == 'code' for cell in book.cells)} code cells")


if __name__ == "__main__":
    command, argument = sys.argv[1:3]
    {"pretend-colab": pretend_colab, "run": run}[command](argument)
