"""The beyond experiment (vdtutorial.experiments.beyond): its comparisons on made-up scores, and the whole
experiment, RL stage included, end to end at a small budget in quick mode."""

import copy
import json
import shutil

import numpy as np
import pytest
import torch

from vdtutorial.demos import Demos
from vdtutorial.experiments import beyond as beyond_module
from vdtutorial.experiments import runs as runs_module
from vdtutorial.experiments.beyond import comparisons, variants
from vdtutorial.experiments.checkpoints import checkpoint_path, default_config
from vdtutorial.experiments.curves import CONFIDENCE
from vdtutorial.experiments.pipeline import pretrained_policy
from vdtutorial.pretrain import PAPER_SIGMA_OPTION
from vdtutorial.runner.resume import ResumeError, check_resumable, read_run_state
from vdtutorial.runner.rows import read_rows, results_file
from vdtutorial.settings import is_quick
from vdtutorial.trpo import TIMING_COLUMNS

pytestmark = pytest.mark.pipeline  # a command, chapter or long run end to end: CI's lock leg only


def _rows(level):
    rng = np.random.default_rng(0)
    return [{"label": v.label, "successes": level(v) + rng.normal(0, 0.5)} for v in variants() for _ in range(5)]


def test_comparisons_are_bonferroni_corrected_and_read_the_right_way():
    # DART far above the Sigma it started from, DAgger far below every hand-set Sigma, the rest equal
    level = {"dart": 20.0, "dagger": 0.0, "hand-set": 10.0}
    found = comparisons(_rows(lambda v: level[v.kind]))
    assert len(found) == 12
    assert all(c["confidence"] == pytest.approx(1 - (1 - CONFIDENCE) / 12) for c in found)
    readings = {(c["question"], c["a"]): c["reading"] for c in found}
    assert readings[("learned noise beats the poor Sigma it started from", "VD, DART from Sigma=0.05")] == "a above b"
    assert readings[("DAgger against the paper's Sigma=0.5", "L2, DAgger")] == "a below b"


def test_the_best_hand_set_sigma_is_chosen_per_regulariser():
    found = comparisons(
        _rows(
            lambda v: (
                {0.25: 15.0}.get(v.sigma, 5.0)
                if v.reg == "vd" and v.kind == "hand-set"
                else {0.05: 15.0}.get(v.sigma, 5.0)
                if v.kind == "hand-set"
                else 5.0
            )
        )
    )
    best = {c["a"].split(",")[0]: c["b"] for c in found if c["question"] == "DAgger against the best hand-set Sigma"}
    assert best == {"VD": "VD, Sigma=0.25", "L2": "L2, Sigma=0.05"}


# ------------------------------------------------------------------------------------------------------------------
# The whole experiment end to end at a small budget: data sets, pre-RL scores, the RL stage, resume, the JSON
# ------------------------------------------------------------------------------------------------------------------
LABELS, STEPS = 60, 400  # expert labels per data set (20 per round), RL env steps per run (2 TRPO iterations)


def _drop_wall_time(rows):
    return [{k: v for k, v in row.items() if k not in TIMING_COLUMNS} for row in rows]


@pytest.fixture(scope="module")
def small_run(tmp_path_factory):
    """beyond() in quick mode with 60 labels per data set and 400 RL steps per run, seeds 0 and 1, a state saved
    after every TRPO iteration; RL starts from the paper's fixed sigma (the figures' fitted one costs a fit per run;
    test_l2_on_a_data_set_made_in_rounds_starts_from_the_vd_spread fits it once)."""
    if not is_quick():
        pytest.skip("runs the whole experiment: quick mode only")
    out = tmp_path_factory.mktemp("beyond") / "whole"
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(beyond_module, "samples", lambda: LABELS)
        record = beyond_module.beyond(
            seeds=(0, 1),
            steps=STEPS,
            out=out,
            workers=1,
            progress=False,
            checkpoint_every=1,
            start_sigma=PAPER_SIGMA_OPTION,
        )
        yield out, record  # the patch holds while the module's tests run


def test_the_rl_stage_makes_a_resumable_run_per_variant_and_seed(small_run):
    out, record = small_run
    rows = read_rows(results_file(out, "beyond"))
    labels = [v.label for v in variants()]
    pre = [r for r in rows if r["stage"] == "pre-RL"]
    rl = [r for r in rows if r["stage"] == "RL"]
    assert sorted((r["label"], r["seed"]) for r in pre) == sorted((label, s) for label in labels for s in (0, 1))
    for label in labels:
        for seed in (0, 1):
            run = [r for r in rl if r["label"] == label and r["seed"] == seed]
            assert [(r["iteration"], r["env_steps"]) for r in run] == [(0, 200), (1, 400)]
    assert {r["method"] for r in rl} == {"vd", "l2"}
    assert len(list((out / "runs").glob("rl_*_seed*.pt"))) == 2 * len(labels)
    assert (out / "beyond_rl.png").stat().st_size > 0


def test_the_rl_stage_starts_from_the_variants_clone_pruned(small_run):
    """TRPO's first iteration is that of the pre-RL stage's clone, pruned: its policy's weights are the clone's."""
    out, _ = small_run
    variant = beyond_module.Variant("dart", "vd", 0.05)
    demos, _ = beyond_module.data_set(variant, out)
    clone = beyond_module.cloned_policy(variant, demos, 1, out).prune_()
    job = beyond_module.RLJob(variant, 1, STEPS, out.resolve(), (out / "runs").resolve(), 1, PAPER_SIGMA_OPTION)
    started, real = [], runs_module.finetune_policy

    def finetune_policy(*args, **kwargs):  # the policy handed to TRPO, as it is before TRPO moves it
        policy = real(*args, **kwargs)
        started.append(copy.deepcopy(policy))
        return policy

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(runs_module, "finetune_policy", finetune_policy)
        steps = runs_module.finetune_steps(
            "vd",
            "reach",
            beyond_module.data_set_path(variant, out),
            seed=1,
            total_steps=200,
            pretrain_config=job.pretrain_config,
            checkpoints_root=out,
        )
        next(steps)
        steps.close()
    assert started[0].state_dict().keys() == clone.state_dict().keys()
    for name, tensor in clone.state_dict().items():
        assert torch.equal(tensor, started[0].state_dict()[name]), name
    assert any(name.endswith("pruned") and bool(tensor.any()) for name, tensor in clone.state_dict().items())


def test_l2_on_a_data_set_made_in_rounds_starts_from_the_vd_spread(small_run):
    """The figures' start sigma for L2 follows the VD network cloned on the same file (and seed)."""
    out, _ = small_run
    variant = beyond_module.Variant("dagger", "l2")
    path = beyond_module.data_set_path(variant, out)
    policy = pretrained_policy("l2", Demos.load(path), "state", 0, default_config("l2"), out, source=path)
    assert policy.pretrain_info["initial_sigma"]["kind"] == "spread"
    assert (out / "checkpoints" / "dagger_l2_vd_state_seed0.pt").exists()
    assert (out / "checkpoints" / "dagger_l2_l2_state_seed0_initsigma-spread.pt").exists()


def test_an_interrupted_rl_run_continues_to_the_rows_of_an_uninterrupted_one(small_run, tmp_path):
    out, record = small_run
    again = tmp_path / "interrupted"
    shutil.copytree(out, again)
    for name in ("beyond.csv.gz", "beyond.json"):
        (again / name).unlink()
    job = beyond_module.RLJob(
        beyond_module.Variant("dagger", "l2"),
        1,
        STEPS,
        again.resolve(),
        (again / "runs").resolve(),
        1,
        PAPER_SIGMA_OPTION,
    )
    job.state_path.unlink()
    steps = job.compute()
    assert next(steps) == {"iteration": 1, "iterations": 2, "env_steps": 200}
    steps.close()  # interrupted after its first iteration
    assert len(read_run_state(job.state_path)["rows"]) == 1
    other = beyond_module.RLJob(job.variant, job.seed, STEPS, job.out, job.state_dir, 1, "spread")
    with pytest.raises(ResumeError, match="initial_sigma: '0.3' -> 'spread'"):
        check_resumable(job.state_path, read_run_state(job.state_path), other.settings, other.rows_expected)
    resumed = beyond_module.beyond(
        seeds=(0, 1),
        steps=STEPS,
        out=again,
        workers=1,
        progress=False,  # samples: LABELS
        checkpoint_every=1,
        start_sigma=PAPER_SIGMA_OPTION,
    )  # (small_run's patch)
    assert _drop_wall_time(read_rows(results_file(again, "beyond"))) == _drop_wall_time(
        read_rows(results_file(out, "beyond"))
    )
    assert resumed["rl"]["claims"] == record["rl"]["claims"]


def test_the_record_holds_the_rl_comparisons_with_holm_verdicts(small_run):
    out, record = small_run
    saved = json.loads((out / "beyond.json").read_text())
    assert saved["rl"]["steps"] == STEPS and "--steps 400" in saved["command"]
    claims = saved["rl"]["claims"]
    assert {c["metric"] for c in claims} == {"successes", "success_rate", "steps_per_trajectory"}
    # per measure: 6 questions per regulariser (as before RL), each at the final level and over the whole run
    assert len(claims) == 3 * 2 * 6 * 2 and {c["measure"] for c in claims} == {"final", "auc"}
    for c in claims:
        assert c["n_a"] == c["n_b"] == 2 and c["low"] <= c["estimate"] <= c["high"]
        assert c["holm_verdict"] in beyond_module.READINGS
        assert c["reading"] == beyond_module.READINGS[c["holm_verdict"]]
    assert len(saved["comparisons"]) == 12  # the pre-RL ones, still there
    # what the experiment cost, summed over every invocation that made a part of it (a resumed grid's wall time is not)
    made = sum(d.get("wall_time_s", 0) for d in saved["data_sets"].values())
    assert saved["run_seconds"] > 0 and made > 0 and saved["data_set_seconds"] == pytest.approx(made)
    assert {c["dagger"] for c in saved["dagger_cost"]} == {"VD, DAgger", "L2, DAgger"}
    for entry in saved["dagger_cost"]:
        assert entry["expert_queries"] == LABELS and entry["clonings"] == beyond_module.rounds()
        assert set(entry["after_rl"]) == {"final", "auc"} and "after 400 RL steps" in entry["statement"]
    assert "successes per 200 steps after 400 RL steps" in beyond_module.format_summary(saved)


def test_the_results_page_tables_hold_every_data_set_and_question(small_run):
    """markdown_tables: a line per data set with its cost and a score per measure, a line per question with both
    stages' differences; the numbers are the record's."""
    _, record = small_run
    tables = beyond_module.markdown_tables(record)
    first, second = tables.split("\n\n")
    data_lines, question_lines = first.splitlines()[2:], second.splitlines()[2:]
    assert [line.split(" | ")[0].lstrip("| ") for line in data_lines] == [v.label for v in variants()]
    assert all(line.count(" | ") == 4 + len(record["rl"]["measures"]) for line in data_lines)
    assert len(question_lines) == len(record["comparisons"]) == 12
    for line, c in zip(question_lines, record["comparisons"]):
        cells = line.strip("| ").split(" | ")
        assert cells[:3] == [c["question"], c["a"], c["b"]] and cells[3].startswith(f"{c['estimate']:+.2f}")
        assert cells[7] in ("confirmed", "contradicted", "not confirmed") and cells[5].startswith(("VD", "L2"))


def test_a_data_set_made_in_rounds_is_named_by_its_file(tmp_path):
    demos = Demos(
        meta={"task": "reach", "samples": 3, "seed": 0, "method": "dart", "rounds_done": 1},
        joints=np.zeros((3, 6)),
        cup=np.zeros((3, 3)),
        actions=np.zeros((3, 6)),
        episode=np.zeros(3, int),
        t=np.arange(3),
    )
    with pytest.raises(ValueError, match="give its path as source"):
        pretrained_policy("l2", demos, checkpoints_root=tmp_path)
    assert (
        checkpoint_path(demos.meta, "l2", "state", 2, tmp_path, data_name="dart_l2_sigma1").name
        == "dart_l2_sigma1_l2_state_seed2.pt"
    )


def test_the_shipped_experiment_has_five_seeds_intervals_and_is_on_the_results_page():
    """Issue 33's record: at least 5 seeds at the full budget; every question before RL and after it with an
    interval and a verdict; what DAgger's queries bought; and the results page shows the record's tables."""
    from pathlib import Path

    from vdtutorial.settings import data_dir

    record = json.loads((data_dir() / "results" / "beyond" / "beyond.json").read_text())
    assert not record["quick"] and len(record["seeds"]) >= 5 and record["rl"]["steps"] == 100_000
    assert record["samples"] == 8000 and len(record["pre_rl"]) == len(variants())
    for c in record["comparisons"] + record["rl"]["claims"]:
        readings = {*beyond_module.READINGS.values(), "a above b", "a below b"}  # after RL / before RL
        assert c["low"] <= c["estimate"] <= c["high"] and c["reading"] in readings
    assert {e["dagger"] for e in record["dagger_cost"]} == {"VD, DAgger", "L2, DAgger"}
    page = (Path(__file__).resolve().parents[1] / "docs" / "results.md").read_text()
    assert beyond_module.markdown_tables(record) in page


def test_the_shipped_rl_claims_are_rederived_from_the_rows(tmp_path):
    """``rederive data/results/beyond`` re-makes the RL claims (the figures' families: the paper's metric, then the
    two secondary measures together; detectable differences; readings) and what DAgger bought from the shipped rows,
    and they are the shipped ones."""
    import shutil

    from vdtutorial.settings import data_dir

    shipped = data_dir() / "results" / "beyond"
    for name in ("beyond.json", "beyond.csv.gz"):
        shutil.copy(shipped / name, tmp_path / name)
    remade = beyond_module.rederive_beyond(tmp_path)
    record = json.loads((shipped / "beyond.json").read_text())
    assert json.loads(json.dumps(remade["rl"]["claims"], default=str)) == record["rl"]["claims"]
    assert json.loads(json.dumps(remade["dagger_cost"], default=str)) == record["dagger_cost"]
    assert {c["family"] for c in record["rl"]["claims"]} == {"primary", "secondary"}
    assert all("detectable" in c and "seeds_needed" not in c for c in record["rl"]["claims"])
