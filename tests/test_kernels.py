"""The CPU kernel pins (vdtutorial.kernels): set where unset, only on x86-64 CPUs with AVX2, and in effect
in a fresh interpreter that imports vdtutorial."""
import json
import os
import subprocess
import sys
import warnings

import pytest

from vdtutorial import kernels
from vdtutorial.kernels import NATIVE_ENV, PINNED, cpu_flags, pin_vector_kernels

PROBE = ("import json, vdtutorial, torch, threadpoolctl; "
         "blas = [i for i in threadpoolctl.threadpool_info() if i['internal_api'] == 'openblas']; "
         "print(json.dumps([torch.backends.cpu.get_cpu_capability(), blas[0].get('architecture') if blas else None]))")


def test_cpu_flags_reads_the_flags_line(tmp_path):
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nmodel name\t: AMD EPYC\nflags\t\t: fpu sse2 avx avx2 fma\n\nprocessor\t: 1\n")
    assert cpu_flags(str(info)) == {"fpu", "sse2", "avx", "avx2", "fma"}
    assert cpu_flags(str(tmp_path / "missing")) == set()


@pytest.mark.parametrize("machine, flags, environ, expected", [
    ("x86_64", {"avx2", "avx512f"}, {}, PINNED),
    ("x86_64", {"avx2"}, {"OPENBLAS_CORETYPE": "Zen"}, {k: v for k, v in PINNED.items() if k != "OPENBLAS_CORETYPE"}),
    ("x86_64", {"avx2"}, {NATIVE_ENV: "1"}, {}),
    ("x86_64", {"avx", "sse4_2"}, {}, {}),  # forcing AVX2 on a CPU without it would stop the process
    ("aarch64", {"avx2"}, {}, {}),
])
def test_pins_are_set_only_where_unset_and_only_on_an_avx2_cpu(monkeypatch, machine, flags, environ, expected):
    monkeypatch.setattr(kernels.platform, "machine", lambda: machine)
    before = dict(environ)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        assert pin_vector_kernels(environ, flags) == expected
    assert environ == {**before, **expected}  # a value the user set is kept
    # numpy is loaded here: too late for its OpenBLAS, which matters (and is said) only on an AVX-512 CPU
    said = any("numpy was imported before vdtutorial" in str(w.message) for w in caught)
    assert said == ("OPENBLAS_CORETYPE" in expected and "avx512f" in flags)


def _probe(**env):
    clean = {k: v for k, v in os.environ.items() if k not in (*PINNED, NATIVE_ENV)}
    out = subprocess.run([sys.executable, "-c", PROBE], env={**clean, **env}, capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.skipif("avx2" not in cpu_flags(), reason="pins only apply on x86-64 CPUs with AVX2")
def test_a_fresh_interpreter_importing_vdtutorial_runs_the_avx2_kernels():
    assert _probe() == ["AVX2", "Haswell"]
    native = _probe(**{NATIVE_ENV: "1"})
    assert native[0] == ("AVX512" if "avx512f" in cpu_flags() and "avx512bw" in cpu_flags() else "AVX2")


@pytest.mark.skipif("avx2" not in cpu_flags(), reason="pins only apply on x86-64 CPUs with AVX2")
def test_this_test_process_runs_the_avx2_kernels():
    """conftest imports vdtutorial before numpy, so the shipped-row regeneration tests run the pinned kernels."""
    import threadpoolctl
    import torch

    assert torch.backends.cpu.get_cpu_capability() == "AVX2"
    blas = [i for i in threadpoolctl.threadpool_info() if i["internal_api"] == "openblas"]
    assert all(i["architecture"] == "Haswell" for i in blas)
