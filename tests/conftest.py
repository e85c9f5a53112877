"""Suite-wide test settings."""

import pytest


@pytest.fixture(autouse=True, scope="session")
def _torch_one_thread():
    """Tests use tiny tensors: one torch thread is faster than two on the 2-core CI machine, and
    immune to other processes competing for the cores."""
    try:
        import torch
    except ImportError:  # pragma: no cover - torch is a core dependency
        yield
        return
    n = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(n)
