"""Shared test settings."""
import vdtutorial  # noqa: F401  (first: it pins the CPU kernels before numpy loads, see vdtutorial.kernels)

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    """Tiny tensors: one torch thread avoids synchronisation costs on a shared 2-core machine."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
