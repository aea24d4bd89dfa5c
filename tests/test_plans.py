"""A pre-registered plan's test: its claims alone are the primary family, and it decides only on its own runs."""

import json
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from vdtutorial.experiments import plans, read_rows, rederive, results_file, write_claims, write_csv
from vdtutorial.experiments.effects import CLAIMS, claims_overview
from vdtutorial.experiments.plans import PLANS, Plan, plan_entry, unmet
from vdtutorial.settings import data_dir

ROOT = Path(__file__).resolve().parents[1]
RESULTS = data_dir() / "results"
#: A shipped record with three seeds per curve, where the plan changes a verdict: "VD ends above the IK expert" has
#: p = 0.024, contradicted on its own and not confirmed after Holm over the record's six claims on the paper's metric.
FOLDER = "fig4_state_fvp0.1"
TEST_PLAN = Plan(
    name="test-plan",
    document="docs/plan-ablations-and-image-fig5.md",
    section="section 1",
    experiment="fig4",
    obs_mode="state",
    curves=("VD", "L2", "no pre-training"),
    seeds=(0, 1, 2),
    total_steps=300_000,
    primary=("VD ends above the IK expert",),
)


@pytest.fixture
def planned_folder(tmp_path, monkeypatch):
    """A copy of the shipped folder, with the test's plan among the plans."""
    monkeypatch.setitem(PLANS, TEST_PLAN.name, TEST_PLAN)
    copy = tmp_path / FOLDER
    shutil.copytree(RESULTS / FOLDER, copy)
    return copy


def _claims(record: dict) -> dict:
    return {(e["text"], e["metric"], e["measure"]): e for e in record["summary"]["claims"]}


def test_the_plans_claims_alone_are_the_primary_family(planned_folder, tmp_path):
    shipped = _claims(json.loads((RESULTS / FOLDER / "fig4.json").read_text()))
    # the same records re-derived without a plan, in this environment: another numpy or scipy (Colab's) may move a
    # p-value in its last digits, and the plan must change none of them here
    plain = _claims(rederive(shutil.copytree(RESULTS / FOLDER, tmp_path / "plain")).record)
    result = rederive(planned_folder, plan=TEST_PLAN.name)
    claims = _claims(result.record)
    key = ("VD ends above the IK expert", "successes", "final")
    assert shipped[key]["p_value"] == pytest.approx(0.0244, abs=5e-4)
    assert (shipped[key]["verdict"], shipped[key]["holm_verdict"]) == ("contradicted", "not confirmed")
    # the plan's one claim: no correction, so its Holm verdict is its plain one; its detectable difference at 5%
    assert claims[key]["family"] == "primary" and claims[key]["planned"] is True
    assert claims[key]["holm_verdict"] == claims[key]["verdict"] == "contradicted"
    assert claims[key]["detectable"] < shipped[key]["detectable"]
    assert [k for k, e in claims.items() if e["family"] == "primary"] == [key]
    # everything else is reported in the secondary family, its numbers unchanged
    assert all(e["p_value"] == plain[k]["p_value"] and "planned" not in e for k, e in claims.items() if k != key)
    secondary = [e for e in claims.values() if e["family"] == "secondary"]
    assert len(secondary) == len(claims) - 1
    assert result.record["plan"]["name"] == "test-plan" and "no Holm correction" in result.record["plan"]["rule"]
    assert "VD ends above the IK expert (pre-registered) | contradicted / **contradicted**" in claims_overview(
        {"test": result.record}
    )
    # the plan stays with the record: a later re-derivation without --plan tests it the same way
    again = rederive(planned_folder)
    assert _claims(again.record)[key] == claims[key] and again.record["plan"] == result.record["plan"]


def test_a_plan_decides_only_on_all_of_its_runs(planned_folder):
    record = json.loads((planned_folder / "fig4.json").read_text())
    assert unmet(TEST_PLAN, record) == []
    short = {**record, "runs": [r for r in record["runs"] if not (r["label"] == "L2" and r["seed"] == 2)]}
    assert unmet(TEST_PLAN, short) == ["L2: seeds [2] not finished (the plan runs seeds [0, 1, 2])"]
    longer = Plan(**{**TEST_PLAN.__dict__, "seeds": (0, 1)})
    assert "VD: seeds [2] beyond the plan's (no extension)" in unmet(longer, record)
    budget = Plan(**{**TEST_PLAN.__dict__, "total_steps": 600_000, "curves": ("VD", "L2")})
    problems = unmet(budget, record)
    assert problems[0] == "curves the plan did not fix: no pre-training"
    assert problems[1].startswith("runs not at the plan's 600000 env steps: l2_reach_n8000_sigma0.5_state_seed0")
    with pytest.raises(ValueError, match="not plan test-plan's as fixed: L2: seeds"):
        plan_entry(TEST_PLAN, short)
    # a planned record that loses a run is refused, and nothing is written
    rederive(planned_folder, plan=TEST_PLAN.name)
    before = (planned_folder / "fig4.json").read_text()
    rows = read_rows(results_file(planned_folder, "fig4"))
    planned = json.loads(before)
    planned["runs"] = short["runs"]
    (planned_folder / "fig4.json").write_text(json.dumps(planned))
    write_csv(results_file(planned_folder, "fig4"), [r for r in rows if not (r["label"] == "L2" and r["seed"] == 2)])
    with pytest.raises(ValueError, match=r"L2: seeds \[2\] not finished"):
        rederive(planned_folder)
    with pytest.raises(ValueError, match=r"L2: seeds \[2\] not finished"):
        write_claims(planned_folder)  # python -m vdtutorial claims: the same check
    assert json.loads((planned_folder / "fig4.json").read_text()) == planned


def test_the_command_line_names_the_plans_and_refuses_an_extension(tmp_path):
    copy = tmp_path / FOLDER
    shutil.copytree(RESULTS / FOLDER, copy)

    def cli(*args):
        return subprocess.run(
            [sys.executable, "-m", "vdtutorial", "rederive", *args], capture_output=True, text=True, cwd=tmp_path
        )

    unknown = cli(str(copy), "--plan", "nonsense")
    assert unknown.returncode == 2 and re.search(
        r"argument --plan: no plan called 'nonsense'; the pre-registered plans are: image-fig5-n2000", unknown.stderr
    )
    other = cli(str(copy), "--plan", "image-fig5-n2000")
    assert other.returncode != 0 and "Traceback" not in other.stderr
    assert "the record is fig4's, the plan runs fig5" in other.stderr
    assert json.loads((copy / "fig4.json").read_text()) == json.loads((RESULTS / FOLDER / "fig4.json").read_text())
    record = json.loads((copy / "fig4.json").read_text())
    (copy / "fig4.json").write_text(json.dumps({**record, "plan": {"name": "image-fig5-n2000"}}))
    extended = cli(str(copy), "--add", str(RESULTS / "fig4"))
    assert extended.returncode != 0 and "its stopping rule adds no seeds after the runs" in extended.stderr


def test_the_image_fig5_plan_is_the_one_its_page_fixed():
    """The registered plan against ``docs/plan-ablations-and-image-fig5.md``, section 1: its claim, seeds, budget,
    methods and folder are the page's, and its claim is one the experiment tests."""
    plan = PLANS["image-fig5-n2000"]
    page = (ROOT / plan.document).read_text()
    section = page.split("## 1. ")[1].split("\n## 2. ")[0]
    assert plan.section == "section 1" and "## 1. Image Fig. 5 at 2000 demonstrations, VD against L2" in page
    command = re.search(r"```\n(python -m vdtutorial experiment fig5 .*?)\n```", section, re.S)[1]
    command = " ".join(command.replace("\\\n", " ").split())
    assert f"--obs {plan.obs_mode} --samples 2000 --methods vd l2" in command
    assert f"--seeds {' '.join(map(str, plan.seeds))} --steps {plan.total_steps}" in command
    assert plan.curves == ("VD, 2000 demos", "L2, 2000 demos") and len(plan.seeds) == 15
    for claim in plan.primary:
        assert f'"{claim}"' in section and any(c.text == claim and c.measure == "final" for c in CLAIMS["fig5"])
    assert "This one claim is the primary family: no Holm correction" in section
    assert "no Holm correction" in plan.rule and plan.rule.startswith(f"pre-registered ({plan.document}")
    assert plans.plan_named("image-fig5-n2000") is plan
    with pytest.raises(ValueError, match="the pre-registered plans are: image-fig5-n2000"):
        plans.plan_named("fig5")
