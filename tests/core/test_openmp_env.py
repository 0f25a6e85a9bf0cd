"""How idle OpenMP threads wait (splat_core.openmp_env): set by the CLI before torch loads, a user's
own setting left alone."""

from __future__ import annotations

import os
import subprocess
import sys

from splat_core.openmp_env import SPIN_COUNT, WAIT_POLICY, openmp_defaults


def test_both_set_when_the_user_set_neither():
    env = {"PATH": "/bin"}
    openmp_defaults(env)
    assert env == {"PATH": "/bin", "OMP_WAIT_POLICY": WAIT_POLICY, "GOMP_SPINCOUNT": SPIN_COUNT}
    assert (WAIT_POLICY, int(SPIN_COUNT)) == ("PASSIVE", 10000)


def test_a_users_setting_of_either_leaves_both_alone():
    for mine in ({"OMP_WAIT_POLICY": "ACTIVE"}, {"GOMP_SPINCOUNT": "0"}, {"OMP_WAIT_POLICY": "PASSIVE"}):
        env = dict(mine)
        openmp_defaults(env)
        assert env == mine


def test_the_cli_sets_them_before_torch_is_imported():
    code = ("import os, sys, app.cli; print(os.environ.get('OMP_WAIT_POLICY'), os.environ.get('GOMP_SPINCOUNT'), "
            "'torch' in sys.modules)")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_WAIT_POLICY", "GOMP_SPINCOUNT")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    assert out.stdout.split() == [WAIT_POLICY, SPIN_COUNT, "False"]
