"""Host-to-device copies that do not make the host wait for the GPU.

`torch.as_tensor(array, device="cuda")` copies from pageable memory, which makes the calling
thread wait until the GPU has run everything queued before the copy: inside an optimisation
loop that is one host synchronisation per iteration. `to_device` stages the array in pinned
memory (torch's caching host allocator) and copies asynchronously on the current stream instead;
on the CPU it is `torch.as_tensor(array, dtype=dtype)`, the same tensor as before.
`mapper_stream` gives the live engine's mapper thread a CUDA stream of its own.
"""

from __future__ import annotations

import contextlib

import numpy as np
import torch


def to_device(array, dtype: torch.dtype, device) -> torch.Tensor:
    if torch.is_tensor(array) and array.device.type != "cpu":
        return array.to(device=device, dtype=dtype)
    t = torch.as_tensor(np.asarray(array), dtype=dtype)
    device = torch.device(device)
    if device.type != "cuda":
        return t.to(device)
    return t.pin_memory().to(device, non_blocking=True)


def mapper_stream(device):
    """On CUDA: the mapper thread's work goes to a stream of its own, so the tracker's kernels
    (on the default stream) never queue behind a mapping step. Versions are handed over with an
    event (SplaTAM.publish / MapVersion.wait_ready). Elsewhere: nothing."""
    device = torch.device(device)
    if device.type != "cuda":
        return contextlib.nullcontext()
    return torch.cuda.stream(torch.cuda.Stream(device))
