"""Test-wide settings: notebooks run in the smoke profile, artifacts go to a temporary folder
(one per worker process when the tests run in parallel), removed when the run ends."""
import os
import shutil
import tempfile

os.environ.setdefault("WMTHESIS_PROFILE", "smoke")
CREATED = None  # the data folder this run made (not one the caller named): removed at the end
if "WMTHESIS_DATA" not in os.environ:
    CREATED = os.environ["WMTHESIS_DATA"] = tempfile.mkdtemp(prefix="wmthesis-test-data-")
if os.environ.get("PYTEST_XDIST_WORKER"):  # each worker process (pytest -n) gets a data folder of its own
    os.environ["WMTHESIS_DATA"] = os.path.join(os.environ["WMTHESIS_DATA"], os.environ["PYTEST_XDIST_WORKER"])
os.environ.setdefault("MPLBACKEND", "Agg")
os.environ.setdefault("OMP_WAIT_POLICY", "PASSIVE")  # as wmthesis sets it; torch is imported below
# The two test workers keep both cores busy: each runs as on a 1-core machine (one torch thread,
# the package's pools in-process), which spares every pool's spawned processes their start.
os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("WMTHESIS_PROCESSES", "1")

import pytest  # noqa: E402
import torch  # noqa: E402


@pytest.fixture
def one_torch_thread():
    """Tiny networks run faster on one thread than on two busy cores (used with usefixtures)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)


def pytest_unconfigure(config):
    """The run's own data folder (every worker's inside it) goes once the run ends."""
    if CREATED is not None and not os.environ.get("PYTEST_XDIST_WORKER"):
        shutil.rmtree(CREATED, ignore_errors=True)
