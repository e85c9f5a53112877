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


@pytest.fixture(scope="session")
def ray_session(tmp_path_factory):
    """ONE local Ray for every test that needs it: 2 CPUs, an 80 MB object store, its temp and token
    files under the test's temp directory (``RAY_TMPDIR``, ``TMPDIR``, ``RAY_AUTH_TOKEN_PATH``); the
    environment is restored afterwards. Skips when ray is not installed (``pip install -e .[fleet]``).
    It is a head node like any other: ``test_fleet`` joins it from a second process (``--address``)
    and kills one of its workers (Ray starts another)."""
    import importlib.util
    import os

    if importlib.util.find_spec("ray") is None:  # not importorskip: Ray must not be imported before start_ray
        pytest.skip("ray is not installed (pip install -e .[fleet])")
    from hybrid_calib.fleet.engines import start_ray

    env = dict(os.environ)
    started = start_ray(2, None, tmp_path_factory.mktemp("ray"), 80)
    import ray

    yield ray
    if started:
        ray.shutdown()
    os.environ.clear()
    os.environ.update(env)


@pytest.fixture
def tiny(tmp_path):
    """The hand-written 3-sample root of tests/tiny_nuscenes.py (no simulator: milliseconds)."""
    from tests.tiny_nuscenes import make_tiny_root

    return make_tiny_root(tmp_path / "tiny", n_samples=3)
