"""The project's own promises: dependency lists agree, notebooks carry no outputs and remove the temporary
folders they make, the quick switch is read in one place, CI runs the README's test command, and every
notebook is under test."""
import json
import re
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def _name(requirement: str) -> str:
    return re.split(r"[<>=!~ \[]", requirement.strip(), maxsplit=1)[0].lower()


def test_environment_yml_matches_pyproject():
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    wanted = {_name(r) for r in project["dependencies"] + project["optional-dependencies"]["test"]}
    listed = set()
    text = (ROOT / "environment.yml").read_text()
    for line in text[text.index("dependencies:"):].splitlines():
        m = re.match(r"\s*-\s+([A-Za-z0-9_.\-]+[^#]*)", line)
        if m and not line.strip().startswith("- pip:"):
            listed.add(_name(m.group(1)))
    listed -= {"python", "pip", "-e"}
    assert listed == wanted


def test_torch_is_pinned_to_one_version_everywhere():
    assert '"torch==2.13.0"' in (ROOT / "pyproject.toml").read_text()
    assert "torch==2.13.0" in (ROOT / "environment.yml").read_text()


def test_notebooks_are_committed_without_outputs():
    notebooks = sorted((ROOT / "notebooks").glob("*.ipynb"))
    assert notebooks
    for nb in notebooks:
        for cell in json.loads(nb.read_text())["cells"]:
            if cell["cell_type"] == "code":
                assert not cell.get("outputs") and cell.get("execution_count") is None, f"{nb.name} has outputs"


def test_notebooks_remove_their_temporary_folders():
    # Learners rerun chapters many times: a temporary folder left by each run would pile up in their /tmp.
    for nb in sorted((ROOT / "notebooks").glob("*.ipynb")):
        code = ["".join(c["source"]) for c in json.loads(nb.read_text())["cells"] if c["cell_type"] == "code"]
        made = {name for cell in code for name in re.findall(r"^(\w+) = Path\(tempfile\.mkdtemp\(", cell, re.M)}
        if made:
            assert "shutil.rmtree(" in code[-1], f"{nb.name}: its last cell removes no folder"
            missing = {name for name in made if not re.search(rf"\b{name}\b", code[-1])}
            assert not missing, f"{nb.name}: the last cell leaves {sorted(missing)} behind"


def test_quick_switch_is_read_in_exactly_one_place():
    readers = [p for p in (ROOT / "vdtutorial").rglob("*.py") if "VDTUTORIAL_QUICK" in p.read_text()]
    assert [p.name for p in readers] == ["settings.py"]
    for nb in (ROOT / "notebooks").glob("*.ipynb"):
        text = nb.read_text()  # notebooks may mention the variable, but read budgets from vdtutorial.settings
        assert "os.environ" not in text and "getenv" not in text, nb.name


def test_ci_runs_the_readme_test_command():
    readme = (ROOT / "README.md").read_text()
    ci = (ROOT / ".ci" / "run").read_text()
    test_line = ci.strip().splitlines()[-1]
    assert test_line.startswith("pytest") and "--nbmake" in test_line and "notebooks" in test_line
    assert test_line in readme
    assert "VDTUTORIAL_QUICK=1" in ci


def test_data_folder_stays_small():
    """The shipped artefacts stay under 30 MB (an experiment's own runs/ and checkpoints/ under data/results/, and
    the per-run CSVs beside the states of a grid in progress, are not shipped: .gitignore)."""
    results = ROOT / "data" / "results"

    def shipped(path):
        if not path.is_file() or not path.is_relative_to(results):
            return path.is_file()
        grid_log = path.parent.name == "state" and path.suffix == ".csv"
        return not ({"runs", "checkpoints"} & set(path.parts) or grid_log)

    size = sum(p.stat().st_size for p in (ROOT / "data").rglob("*") if shipped(p))
    assert size < 30 * 2**20
