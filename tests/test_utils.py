"""wmthesis.utils: worker pools that do not outlive their driver."""
import os
import signal
import subprocess
import sys
import textwrap
import time

import pytest

DRIVER = textwrap.dedent("""
    import os, sys, time
    from wmthesis.utils import parallel_calls

    def nap(folder):
        open(os.path.join(folder, str(os.getpid())), "w").close()
        time.sleep(120)

    if __name__ == "__main__":
        parallel_calls([(nap, sys.argv[1]), (nap, sys.argv[1])], progress=False)
""")


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/status") as f:
            return "\nState:\tZ" not in f.read()  # a zombie has ended
    except FileNotFoundError:
        return False


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="the parent-death signal is Linux's")
def test_a_killed_driver_leaves_no_worker_computing_on(tmp_path):
    (tmp_path / "driver.py").write_text(DRIVER)
    pids = tmp_path / "pids"
    pids.mkdir()
    driver = subprocess.Popen([sys.executable, str(tmp_path / "driver.py"), str(pids)],
                              env={**os.environ, "WMTHESIS_PROCESSES": "2"})  # a pool, as on 2 cores
    deadline = time.time() + 120
    while len(os.listdir(pids)) < 2 and time.time() < deadline:
        time.sleep(0.2)
    workers = [int(name) for name in os.listdir(pids)]
    assert len(workers) == 2 and all(_alive(pid) for pid in workers)
    driver.send_signal(signal.SIGKILL)  # no clean-up runs in the driver
    driver.wait()
    deadline = time.time() + 20
    while any(_alive(pid) for pid in workers) and time.time() < deadline:
        time.sleep(0.2)
    assert not any(_alive(pid) for pid in workers)
