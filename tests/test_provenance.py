"""Every command a shipped file records remakes that file (issue 44): each is parsed by the command line it names
(no run) and must name the file's own output -- an experiment record its folder, a data set or a checkpoint its
file name -- and, for a record merged from several commands, list each part and the merge that joined them."""

import json
import shlex
import zipfile
from pathlib import Path

import pytest

from vdtutorial.cli.commands import demos_output, pretrain_output
from vdtutorial.cli.parser import build_parser
from vdtutorial.experiments import sigma_study
from vdtutorial.experiments.results import NOT_RECORDED
from vdtutorial.experiments.pipeline import made_in_rounds
from vdtutorial.runner.compressed import load_compressed
from vdtutorial.settings import data_dir

DATA = data_dir()
ROOT = DATA.parent


def parse(command: str):
    """``command`` parsed by the command line it names, as it would be before running."""
    argv = shlex.split(command)
    if argv[:3] == ["python", "-m", "vdtutorial.experiments.sigma_study"]:
        return sigma_study.build_parser().parse_args(argv[3:])
    assert argv[:3] == ["python", "-m", "vdtutorial"], command
    return build_parser().parse_args(argv[3:])


def _commands(node, found):
    """Every string under a ``command`` key, anywhere in a JSON record."""
    if isinstance(node, dict):
        for key, value in node.items():
            if key == "command" and isinstance(value, str):
                found.append(value)
            else:
                _commands(value, found)
    elif isinstance(node, list):
        for value in node:
            _commands(value, found)
    return found


RECORDS = sorted(p.relative_to(DATA).as_posix() for p in (DATA / "results").glob("*/*.json"))
TABLES = sorted(p.relative_to(DATA).as_posix() for p in (DATA / "results").glob("table1*/*.txt"))
DEMOS = sorted(p.relative_to(DATA).as_posix() for p in DATA.rglob("*.npz"))
CHECKPOINTS = sorted(
    p.relative_to(DATA).as_posix() for p in DATA.rglob("*.pt") if "state" not in p.parts and "checkpoints" in p.parts
)


def _folder(path: str) -> str:
    return (Path("data") / path).parent.as_posix()


@pytest.mark.parametrize("path", RECORDS)
def test_every_command_of_a_record_parses_and_writes_its_folder(path):
    record = json.loads((DATA / path).read_text())
    commands = _commands(record, [])
    assert commands, f"{path} records no command"
    for command in commands:
        parse(command)
    merged = record.get("merged") or []
    assert parse(record["command"]).out == _folder(path), f"{path}: {record['command']}"
    runs, merges = [e for e in merged if "seeds" in e], [e for e in merged if "seeds" not in e]
    added = {other for e in merges for args in [parse(e["command"])] for other in args.add + args.add_other_cpu}
    for entry in merges:
        assert parse(entry["command"]).folders == [_folder(path)], entry["command"]
    for entry in runs:  # each part wrote the record's folder, or a folder a merge added to it
        args = parse(entry["command"])
        assert args.out == _folder(path) or args.out in added, entry["command"]
        assert args.seeds == entry["seeds"] and entry["kernels"] is not None
    if merged:
        assert sorted({s for e in runs for s in e["seeds"]}) == record["seeds"] and record["argv"] is None
        # a part that names its curves ("labels") may share seeds with another curve's part, never its own curve's;
        # parts merged before curves were named hold disjoint seeds
        labelled = [(label, s) for e in runs if "labels" in e for label in e["labels"] for s in e["seeds"]]
        unlabelled = [s for e in runs if "labels" not in e for s in e["seeds"]]
        assert len(labelled) == len(set(labelled)) and len(unlabelled) == len(set(unlabelled))
        assert (
            len(added) == len(runs) - 1
            and record["kernels"] == "mixed"
            or all(e["kernels"] == runs[0]["kernels"] for e in runs)
        )


def test_the_merged_records_name_the_merge_and_each_parts_kernels():
    """The state figures' seeds 5-9 ran apart, on other kernels, and were merged: their records say so."""
    for fig in ("fig4", "fig5", "fig6", "fig7"):
        merged = json.loads((DATA / "results" / fig / f"{fig}.json").read_text())["merged"]
        assert [e.get("seeds") for e in merged[:3]] == [[0, 1, 2, 3, 4], [5, 6, 7, 8, 9], None]
        assert merged[0]["kernels"] == NOT_RECORDED and isinstance(merged[1]["kernels"], dict)
        assert (
            merged[2]["command"] == f"python -m vdtutorial rederive data/results/{fig} --add-other-cpu "
            f"runs/{fig}_state_seeds5-9"
        )
        # Fig. 5's 2000-demonstration set has more seeds: their command names that data set and those methods only
        assert len(merged) == (5 if fig == "fig5" else 3)
    more = json.loads((DATA / "results" / "fig5" / "fig5.json").read_text())["merged"][3]
    args = parse(more["command"])
    assert args.samples == [2000] and sorted(args.methods) == ["l2", "vd"] and more["seeds"] == list(range(10, 23))


@pytest.mark.parametrize("path", TABLES)
def test_a_table1_command_writes_its_folder(path):
    line = next(line for line in (DATA / path).read_text().splitlines() if line.startswith("command: "))
    args = parse(line.removeprefix("command: "))
    assert args.out == _folder(path) and args.name == "table1"
    assert args.kl_weighting == Path(path).stem.removeprefix("table1_")


@pytest.mark.parametrize("path", DEMOS)
def test_a_data_set_command_makes_a_file_of_its_name(path):
    """A data set made in rounds (DART's, DAgger's) has no command of its own: the experiment that made it, whose
    record lies one folder up, writes that folder."""
    meta = json.loads(zipfile.ZipFile(DATA / path).read("meta.json"))
    if made_in_rounds(meta):
        record = (DATA / path).parents[1] / "beyond.json"
        assert parse(json.loads(record.read_text())["command"]).out == _folder(path).rsplit("/", 1)[0]
        return
    args = parse(meta["command"])
    assert demos_output(args).name == Path(path).name and args.seed == meta["seed"]


@pytest.mark.parametrize("path", CHECKPOINTS)
def test_a_checkpoint_command_makes_a_file_of_its_name_from_a_shipped_data_set(path):
    """Its name holds the data set, regulariser, observation, seed, start sigma and early stop: a command that left
    out ``--patience`` (as the stopped image checkpoint's once did) would make another file."""
    meta = load_compressed(DATA / path)["meta"]
    args = parse(meta["command"])
    demos = ROOT / args.demos
    assert demos.exists(), f"{path}: {args.demos} is not shipped"
    demos_meta = json.loads(zipfile.ZipFile(demos).read("meta.json"))
    assert pretrain_output(args, demos_meta).name == Path(path).name, meta["command"]
    assert args.patience == meta["config"].get("patience")
