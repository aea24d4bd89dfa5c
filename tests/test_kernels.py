"""The CPU kernel pins (vdtutorial.runner.kernels): set only when asked (never by ``import vdtutorial``), only
where unset and only on x86-64 CPUs with AVX2; ``--exact-kernels`` starts a command again with them in effect."""

import json
import os
import subprocess
import sys
import warnings

import pytest

from vdtutorial.runner import kernels
from vdtutorial.runner.kernels import PINNED, cpu_flags, cpu_model, kernel_settings, pin_vector_kernels

PROBE = (
    "import json, vdtutorial, torch, threadpoolctl; "
    "blas = [i for i in threadpoolctl.threadpool_info() if i['internal_api'] == 'openblas']; "
    "print(json.dumps([torch.backends.cpu.get_cpu_capability(), blas[0].get('architecture') if blas else None]))"
)


def test_cpu_flags_reads_the_flags_line(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: fpu sse2 avx avx2 fma\n\nprocessor\t: 1\n")
    assert cpu_flags(str(info)) == {"fpu", "sse2", "avx", "avx2", "fma"}
    assert cpu_flags(str(tmp_path / "missing")) == set()


def test_the_record_names_the_cpu_model_beside_the_kernels(tmp_path, monkeypatch):
    """Two machines with the same recorded kernels may still round differently (an Intel CPU's MKL against an AMD
    one's), so a record's kernels carry the model name, which Linux gives once per core."""
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: AMD EPYC 9B14\n\nprocessor\t: 1\nmodel name\t: AMD EPYC 9B14\n")
    assert cpu_model(str(info)) == "AMD EPYC 9B14"
    monkeypatch.setattr(kernels.platform, "processor", lambda: "arm")
    assert cpu_model(str(tmp_path / "missing")) == "arm"
    assert set(kernel_settings()) == {"torch_cpu_capability", *PINNED, "cpu"}


@pytest.mark.parametrize(
    "machine, flags, environ, expected",
    [
        ("x86_64", {"avx2", "avx512f"}, {}, PINNED),
        (
            "x86_64",
            {"avx2"},
            {"OPENBLAS_CORETYPE": "Zen"},
            {k: v for k, v in PINNED.items() if k != "OPENBLAS_CORETYPE"},
        ),
        ("x86_64", {"avx", "sse4_2"}, {}, {}),  # forcing AVX2 on a CPU without it would stop the process
        ("aarch64", {"avx2"}, {}, {}),
    ],
)
def test_pins_are_set_only_where_unset_and_only_on_an_avx2_cpu(monkeypatch, machine, flags, environ, expected):
    monkeypatch.setattr(kernels.platform, "machine", lambda: machine)
    before = dict(environ)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert pin_vector_kernels(environ, flags) == expected
    assert environ == {**before, **expected}  # a value the user set is kept
    assert not caught  # another process's environment: this process's numpy has nothing to do with it


@pytest.mark.parametrize("flags", [{"avx2", "avx512f"}, {"avx2"}], ids=["avx512", "avx2"])
def test_pinning_this_process_after_numpy_loaded_warns_on_an_avx512_cpu(monkeypatch, flags):
    """numpy is loaded here: too late for its OpenBLAS, which matters (and is said) only on an AVX-512 CPU."""
    monkeypatch.setattr(kernels.platform, "machine", lambda: "x86_64")
    for name in PINNED:
        monkeypatch.delenv(name, raising=False)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert pin_vector_kernels(os.environ, flags) == PINNED
    said = any("numpy was loaded before the kernels were pinned" in str(w.message) for w in caught)
    assert said == ("avx512f" in flags)


def _probe(*args, code=PROBE, **env):
    """Run ``code`` (default: print the kernels in use) in a fresh interpreter whose environment has no pins."""
    clean = {k: v for k, v in os.environ.items() if k not in PINNED}
    out = subprocess.run(
        [sys.executable, *args, "-c", code], env={**clean, **env}, capture_output=True, text=True, check=True
    )
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.parametrize("first", ["", "import numpy, torch, gymnasium; "], ids=["alone", "after numpy"])
def test_importing_vdtutorial_changes_nothing_in_the_environment(first):
    code = (
        f"import json, os, warnings; {first}before = dict(os.environ)\n"
        "with warnings.catch_warnings(record=True) as caught:\n"
        "    warnings.simplefilter('always'); import vdtutorial, vdtutorial.experiments\n"
        "ours = [str(w.message) for w in caught if 'vdtutorial' in w.filename]\n"
        "print(json.dumps([dict(os.environ) == before, ours]))"
    )
    assert _probe(code=code) == [True, []]  # other packages' deprecation warnings (Colab's matplotlib) are theirs


@pytest.mark.skipif("avx2" not in cpu_flags(), reason="pins only apply on x86-64 CPUs with AVX2")
def test_a_learners_interpreter_runs_the_cpus_own_kernels():
    native = _probe()
    assert native[0] == ("AVX512" if "avx512f" in cpu_flags() and "avx512bw" in cpu_flags() else "AVX2")
    assert _probe(**PINNED) == ["AVX2", "Haswell"]


def _first_kernels_line(*options) -> str:
    """The line in which ``bench env`` names its CPU kernels, from a fresh unpinned environment (then stopped)."""
    clean = {k: v for k, v in os.environ.items() if k not in PINNED}
    bench = subprocess.Popen(
        [sys.executable, "-m", "vdtutorial", "bench", "env", *options],
        env=clean,
        stdout=subprocess.PIPE,
        stderr=subprocess.DEVNULL,
        text=True,
    )
    try:
        return next(line.strip() for line in bench.stdout if line.startswith("CPU kernels:"))
    finally:
        bench.kill()
        bench.wait()


@pytest.mark.skipif("avx2" not in cpu_flags(), reason="pins only apply on x86-64 CPUs with AVX2")
def test_exact_kernels_starts_the_command_again_with_the_pins():
    assert _first_kernels_line("--exact-kernels") == "CPU kernels: AVX2 (pinned, --exact-kernels)"
    assert _first_kernels_line().endswith("(this CPU's own)")


def test_exact_kernels_inside_a_process_is_refused_with_a_reason(monkeypatch, capsys):
    from vdtutorial.__main__ import main

    for name in PINNED:
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setattr(kernels, "cpu_flags", lambda: {"avx2"})
    monkeypatch.setattr(kernels.platform, "machine", lambda: "x86_64")
    assert main(["bench", "env", "--exact-kernels"]) == 2
    assert "restarts the command" in capsys.readouterr().err


@pytest.mark.skipif("avx2" not in cpu_flags(), reason="pins only apply on x86-64 CPUs with AVX2")
def test_this_test_process_runs_the_avx2_kernels():
    """conftest pins the kernels before numpy loads, so the shipped-row regeneration tests run the AVX2 kernels."""
    import threadpoolctl
    import torch

    assert torch.backends.cpu.get_cpu_capability() == "AVX2"
    blas = [i for i in threadpoolctl.threadpool_info() if i["internal_api"] == "openblas"]
    assert all(i["architecture"] == "Haswell" for i in blas)
