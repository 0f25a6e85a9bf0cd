"""The CPU target the Numba kernels compile for (splat_core.parallel.prefer_512_bit_vectors), and
the warm-up's check that they are compiled for it (app.warmup.kernels_compiled).

Each case runs in a fresh interpreter: the target is fixed once Numba's first kernel exists.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest
import torch
from llvmlite import binding as llvm

from splat_core.render.cpu import rasterize_cpu

TARGET = """
import json
import splat_core.render.cpu
from numba.core.registry import cpu_target
from splat_core.parallel import prefer_512_bit_vectors
from app.warmup import kernels_compiled
print(json.dumps({"features": cpu_target.target_context.codegen()._tm_features,
                  "wide": prefer_512_bit_vectors(), "compiled": kernels_compiled()}))
"""
try:
    HOST = llvm.get_host_cpu_features()
except RuntimeError:        # LLVM reports no features for this host (not x86): nothing to choose
    pytest.skip("LLVM reports no CPU features on this host", allow_module_level=True)


def _target(**env) -> dict:
    environ = {k: v for k, v in os.environ.items() if k not in ("NUMBA_CPU_FEATURES", "NUMBA_CPU_NAME")}
    out = subprocess.run([sys.executable, "-c", TARGET], env=dict(environ, **env), capture_output=True,
                         text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_kernels_target_512_bit_vectors_where_the_cpu_has_avx512():
    got = _target()
    if HOST.get("avx512f"):
        assert got["wide"] and got["features"] == HOST.flatten() + ",-prefer-256-bit"
    else:
        assert not got["wide"] and got["features"] == HOST.flatten()


def test_a_users_cpu_features_win():
    got = _target(NUMBA_CPU_FEATURES=HOST.flatten())
    assert not got["wide"] and got["features"] == HOST.flatten()


def test_kernels_compiled_means_compiled_for_this_target():
    # Compile (or load) the forward kernel for this process's target, then ask from this target and
    # from one nothing was compiled for (its features differ, so Numba's cache has no entry for it).
    means = torch.tensor([[8.0, 8.0]])
    rasterize_cpu(means, torch.tensor([[0.5, 0.0, 0.5]]), torch.tensor([0.9]), torch.ones(1, 4),
                  torch.ones(1), torch.ones(1, dtype=torch.int32), 16, 16)
    assert _target()["compiled"]
    other = _target(NUMBA_CPU_FEATURES=HOST.flatten() + ",+prefer-256-bit,+prefer-128-bit")
    assert not other["compiled"]
