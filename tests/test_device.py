"""``--device cuda`` (issue 31): pre-training and TRPO's update on a GPU where there is one, the CPU unchanged.

This project's machine has no GPU: here the tests check that a missing GPU is refused in one line before any
work, and that ``device="cpu"`` given explicitly is the default bit for bit. The tests that run on a GPU
(skipped without one) compare its numbers with the CPU's."""

import dataclasses

import numpy as np
import pytest
import torch

from vdtutorial.__main__ import main
from vdtutorial.demos import Demos, demo_path
from vdtutorial.envs import ENV_IDS
from vdtutorial.experiments import NUM_ENVS
from vdtutorial.experiments.checkpoints import checkpoint_path, load_checkpoint
from vdtutorial.policy import on_device, torch_device
from vdtutorial.pretrain import PretrainConfig, pretrain
from vdtutorial.rollout import make_vec_env
from vdtutorial.trpo import TIMING_COLUMNS, TRPO, TRPOConfig

HAS_CUDA = torch.cuda.is_available()
NO_GPU = "error: --device cuda: this machine has no CUDA GPU (torch.cuda.is_available() is False)"
SHIPPED_DEMOS = demo_path("reach", 8000, 0.5, 0)


@pytest.fixture(scope="module")
def small_demos():
    """The first 300 samples of the shipped reach set (about 12 episodes)."""
    demos = Demos.load(SHIPPED_DEMOS)
    return Demos(
        **{k: getattr(demos, k)[:300] for k in ("joints", "cup", "actions", "episode", "t")},
        meta={**demos.meta, "samples": 300},
    )


def _pruned(obs_mode: str):
    """The shipped VD policy pre-trained on the 8000-sample reach set (seed 0), pruned for RL."""
    return load_checkpoint(checkpoint_path(Demos.load(SHIPPED_DEMOS).meta, "vd", obs_mode, 0)).prune_()


def _on_cpu(module: torch.nn.Module) -> bool:
    return all(t.device.type == "cpu" for t in [*module.parameters(), *module.buffers()])


# -- no GPU here: refused in one line, before any work --------------------------------------------------
@pytest.mark.skipif(HAS_CUDA, reason="this machine has a CUDA GPU")
@pytest.mark.parametrize(
    "argv",
    [
        ["pretrain", "--reg", "l2", "--demos", str(SHIPPED_DEMOS), "--device", "cuda"],
        ["bench", "finetune", "--device", "cuda"],
        ["experiment", "fig4", "--device", "cuda"],
    ],
    ids=["pretrain", "bench", "experiment"],
)
def test_cuda_without_a_gpu_is_one_line_and_exit_2(argv, tmp_path, capsys):
    out = tmp_path / "out"
    code = main(argv + ["--out", str(out)] if argv[0] != "bench" else argv)
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and err[-1] == NO_GPU
    assert not out.exists()  # refused before anything was made


@pytest.mark.skipif(HAS_CUDA, reason="this machine has a CUDA GPU")
def test_the_library_refuses_cuda_before_any_work(small_demos):
    with pytest.raises(ValueError, match=r"^device cuda: this machine has no CUDA GPU"):
        torch_device("cuda")
    with pytest.raises(ValueError, match="no CUDA GPU"):  # before the policy is built or an image rendered
        pretrain(small_demos, PretrainConfig(reg="l2", epochs=1), progress=False, device="cuda")
    env = make_vec_env(ENV_IDS["reach"], NUM_ENVS, obs_mode="state")
    with pytest.raises(ValueError, match="no CUDA GPU"):
        TRPO(_pruned("state"), env, device="cuda")
    env.close()


@pytest.mark.parametrize(
    "argv, message",
    [
        (["bench", "env", "--device", "cpu", "--profile"], "error: --profile is an option of bench finetune only"),
        (["bench", "policy", "--device", "cuda"], "error: --device is an option of bench finetune only"),
        (
            ["experiment", "table1", "--device", "cuda"],
            "error: table1 pre-trains only (no TRPO runs to resume): --device is an option of the figures",
        ),
    ],
)
def test_device_is_refused_where_it_does_not_apply(argv, message, capsys):
    assert main(argv) == 2
    assert capsys.readouterr().err.strip().splitlines()[-1] == message


def test_an_unknown_device_is_a_one_line_usage_error(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["pretrain", "--reg", "vd", "--demos", str(SHIPPED_DEMOS), "--device", "tpu"])
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and len(err.strip().splitlines()) == 1
    assert "argument --device: invalid choice: 'tpu'" in err
    for name, reason in (("tpu", "expected cpu, cuda or cuda:N"), ("mps", "expected cpu, cuda or cuda:N")):
        with pytest.raises(ValueError, match=f"^--device {name}: {reason}$"):
            torch_device(name, "--device")
    assert torch_device("cpu") == torch.device("cpu") == torch_device(torch.device("cpu"))


# -- the CPU unchanged -----------------------------------------------------------------------------------
def test_explicit_cpu_pretraining_is_the_default_bit_for_bit(small_demos):
    config = PretrainConfig(reg="vd", epochs=3)
    default, history = pretrain(small_demos, config, seed=1, progress=False)
    explicit, explicit_history = pretrain(small_demos, config, seed=1, progress=False, device="cpu")
    assert explicit_history == history and len(history) == 3 and history[-1]["weights_pruned"] > 0
    assert all(torch.equal(a, b) for a, b in zip(default.state_dict().values(), explicit.state_dict().values()))


def _one_iteration(fvp_subsample: float, **device) -> tuple[dict, dict]:
    torch.manual_seed(0)
    env = make_vec_env(ENV_IDS["reach"], NUM_ENVS, obs_mode="state")
    algo = TRPO(_pruned("state"), env, TRPOConfig(fvp_subsample=fvp_subsample), seed=3, **device)
    params = algo.params
    row = {k: v for k, v in algo.iterate().items() if k not in TIMING_COLUMNS}
    algo.close()
    assert [id(p) for p in params] == [id(p) for p in algo.policy.parameters() if p.requires_grad]
    return row, algo.policy.state_dict()


@pytest.mark.parametrize("fvp_subsample", [1.0, 0.1])
def test_explicit_cpu_trpo_gives_the_default_rows_bit_for_bit(fvp_subsample):
    default_row, default_state = _one_iteration(fvp_subsample)
    row, state = _one_iteration(fvp_subsample, device="cpu")
    assert row == default_row and row["line_search"] != "rejected" and row["mean_kl"] > 0
    assert all(torch.equal(default_state[k], state[k]) for k in default_state)


def test_on_device_moves_the_module_back_to_the_cpu_after_an_error():
    """Module.to keeps the Parameter objects (TRPO's ``params`` list stays valid); a dtype move shows it on
    a CPU-only machine, as a move to a GPU and back would."""
    net = torch.nn.Linear(3, 2)
    weight = net.weight
    with pytest.raises(RuntimeError, match="inside"):
        with on_device(net.to(torch.float64), torch.device("cpu")):
            raise RuntimeError("inside")
    assert net.weight is weight and _on_cpu(net)


# -- on a GPU: the same numbers up to rounding, and the policy back on the CPU ---------------------------
@pytest.mark.skipif(not HAS_CUDA, reason="no CUDA GPU on this machine")
def test_pretraining_on_cuda_matches_the_cpu(small_demos):
    config = PretrainConfig(reg="l2", epochs=3)  # L2: no weight noise, so only rounding differs
    cpu_policy, cpu_history = pretrain(small_demos, config, seed=1, progress=False)
    gpu_policy, gpu_history = pretrain(small_demos, config, seed=1, progress=False, device="cuda")
    assert _on_cpu(gpu_policy)
    for cpu_row, gpu_row in zip(cpu_history, gpu_history):
        for key in ("train_loss", "val_mse", "val_loglik"):
            assert gpu_row[key] == pytest.approx(cpu_row[key], rel=1e-3), key
    vd_policy, vd_history = pretrain(small_demos, dataclasses.replace(config, reg="vd"), progress=False, device="cuda")
    assert _on_cpu(vd_policy) and np.isfinite([row["train_loss"] for row in vd_history]).all()
    assert 0 <= vd_history[-1]["weights_pruned"] <= 1


@pytest.mark.skipif(not HAS_CUDA, reason="no CUDA GPU on this machine")
def test_a_trpo_update_of_the_image_policy_on_cuda_matches_the_cpu():
    env = make_vec_env(ENV_IDS["reach"], NUM_ENVS, obs_mode="rgbd", image_size=128)
    cpu, gpu = (TRPO(_pruned("rgbd"), env, seed=0, device=device) for device in ("cpu", "cuda"))
    batch = cpu.collect()
    gpu_stats, cpu_stats = gpu.update(batch), cpu.update(batch)
    env.close()
    assert _on_cpu(gpu.policy) and batch.actions.device.type == "cpu"
    assert [id(p) for p in gpu.params] == [id(p) for p in gpu.policy.parameters() if p.requires_grad]
    assert cpu_stats["line_search"] != "rejected" and gpu_stats["line_search"] == cpu_stats["line_search"]
    for key in ("mean_kl", "surrogate_improvement", "entropy"):
        assert gpu_stats[key] == pytest.approx(cpu_stats[key], rel=1e-3), key
    for a, b in zip(cpu.policy.parameters(), gpu.policy.parameters()):
        assert torch.allclose(a, b, rtol=1e-3, atol=1e-4)
