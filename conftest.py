"""Test-wide settings: notebooks run in the smoke profile, artifacts go to a temporary folder
(one per worker process when the tests run in parallel)."""
import os
import tempfile

os.environ.setdefault("WMTHESIS_PROFILE", "smoke")
os.environ.setdefault("WMTHESIS_DATA", tempfile.mkdtemp(prefix="wmthesis-test-data-"))
if os.environ.get("PYTEST_XDIST_WORKER"):  # each worker process (pytest -n) gets a data folder of its own
    os.environ["WMTHESIS_DATA"] = os.path.join(os.environ["WMTHESIS_DATA"], os.environ["PYTEST_XDIST_WORKER"])
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as wmthesis sets it; torch is imported below

import pytest  # noqa: E402
import torch  # noqa: E402


@pytest.fixture
def one_torch_thread():
    """Tiny networks run faster on one thread than on two busy cores (used with usefixtures)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
