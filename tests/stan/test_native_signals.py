"""Native backend: the driver never outlives the Python process that started it (SIGTERM,
SIGINT, SIGKILL of the parent), and SIGTERM/SIGINT still remove the run's temporaries."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
from ssmobs.stan_backends import stan_file
from ssmobs.stan_backends.native import NativeBackend
from test_backends import _data

pytestmark = pytest.mark.stan

WORKFLOW_DIR = Path(__file__).resolve().parents[2] / "workflow"

#: a run that takes far longer than the test: warmup draws are not kept, so this costs no
#: memory.  It turns Ctrl-C into KeyboardInterrupt as an interactive Python does: a Python
#: started from a background job (`make test &`, nohup) inherits SIGINT ignored.
LONG_RUN = (
    "import json, signal, sys\n"
    "signal.signal(signal.SIGINT, signal.default_int_handler)\n"
    "from ssmobs.stan_backends import SamplerSettings, stan_file\n"
    "from ssmobs.stan_backends.native import NativeBackend\n"
    "b = NativeBackend(tmp_root=sys.argv[1])\n"
    "b.sample(stan_file('same'), json.load(open(sys.argv[2])), 1,\n"
    "         SamplerSettings(chains=1, iter_warmup=10**9, iter_sampling=1))\n"
)


def _drivers(pid: int) -> list[int]:
    """Children of ``pid`` that run the native driver (not stanc, asked for its version)."""
    found = []
    for entry in Path("/proc").iterdir():
        if not entry.name.isdigit():
            continue
        try:
            stat = (entry / "stat").read_text()
        except OSError:
            continue
        # pid (comm) state ppid ...; comm may hold spaces and parentheses
        fields = stat[stat.rindex(")") + 2 :].split()
        if int(fields[1]) != pid:
            continue
        try:
            argv0 = (entry / "cmdline").read_bytes().split(b"\0")[0]
        except OSError:
            continue
        if argv0.endswith(b"/driver"):
            found.append(int(entry.name))
    return found


def _running(pid: int) -> bool:
    """True while ``pid`` exists and is not a zombie (an unreaped corpse is gone for us)."""
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat[stat.rindex(")") + 2] not in "ZX"


@pytest.fixture(scope="module")
def built() -> None:
    NativeBackend().compile(stan_file("same"))  # so the child only looks it up


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc (Linux)")
@pytest.mark.parametrize("signum", [signal.SIGTERM, signal.SIGINT, signal.SIGKILL])
def test_driver_dies_with_its_parent(built, tmp_path, signum):
    runs = tmp_path / "runs"
    runs.mkdir()
    data = tmp_path / "data.json"
    data.write_text(json.dumps(_data("same", {"a": 0.9})))
    env = dict(os.environ, PYTHONPATH=str(WORKFLOW_DIR))
    parent = subprocess.Popen(
        [sys.executable, "-c", LONG_RUN, str(runs), str(data)],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    drivers: list[int] = []
    try:
        deadline = time.monotonic() + 120
        while not drivers and time.monotonic() < deadline and parent.poll() is None:
            time.sleep(0.1)
            drivers = _drivers(parent.pid)
        assert drivers, f"no driver started: {parent.communicate()[1][-2000:]}"
        time.sleep(0.5)  # the driver is sampling now
        assert _running(drivers[0])
        os.kill(parent.pid, signum)
        parent.wait(timeout=30)
        deadline = time.monotonic() + 5
        while _running(drivers[0]) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _running(drivers[0]), "the driver outlived its parent"
        if signum == signal.SIGTERM:
            assert parent.returncode == -signal.SIGTERM  # still ends as SIGTERM does
        if signum != signal.SIGKILL:  # cleanups ran: the run's directory is gone
            assert list(runs.iterdir()) == []
    finally:
        for pid in drivers:
            if _running(pid):
                os.kill(pid, signal.SIGKILL)
        if parent.poll() is None:
            parent.kill()
        parent.communicate()
