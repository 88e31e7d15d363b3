"""The environment the native driver runs in: glibc's per-thread cache of freed blocks made
large enough for a NUTS step (issue 49), without overriding what a user set."""

from __future__ import annotations

import pytest
from ssmobs.stan_backends.native_run import MALLOC_TUNABLE, driver_environment, run_driver

pytestmark = pytest.mark.unit


def test_the_tcache_tunable_is_added_to_the_environment():
    env = driver_environment({"PATH": "/bin"})
    assert env == {"PATH": "/bin", "GLIBC_TUNABLES": MALLOC_TUNABLE}


def test_other_tunables_are_kept():
    env = driver_environment({"GLIBC_TUNABLES": "glibc.malloc.arena_max=2"})
    assert env["GLIBC_TUNABLES"] == f"glibc.malloc.arena_max=2:{MALLOC_TUNABLE}"


def test_a_tcache_count_the_user_set_wins():
    mine = "glibc.malloc.tcache_count=16"
    assert driver_environment({"GLIBC_TUNABLES": mine})["GLIBC_TUNABLES"] == mine


def test_the_driver_process_sees_it(monkeypatch):
    monkeypatch.delenv("GLIBC_TUNABLES", raising=False)
    returncode, output = run_driver(["sh", "-c", 'printf "%s" "$GLIBC_TUNABLES"'])
    assert (returncode, output) == (0, MALLOC_TUNABLE)
