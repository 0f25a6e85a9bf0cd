"""GaussianMap: the map's parameters, their activations, append / prune, birth frame.

Parameters are stored raw (before activation), as in 3DGS and SplaTAM:
    means            N x 3  world coordinates (metres)
    colors           N x 3  RGB used directly (no activation, may leave [0, 1])
    rotations        N x 4  unnormalised quaternion (w, x, y, z); unused by isotropic rendering
    logit_opacities  N      opacity = sigmoid(logit)
    log_scales       N x 1  (isotropic) or N x 3 (anisotropic); scale = exp(log_scale)
`birth_frame` (N, int64) is the frame index at which each Gaussian was created; the viewer uses
it to show the map as it was at a keyframe. `guessed` (N, bool) marks a Gaussian placed where the
frame had no depth (densify.hole_fill: at a depth guessed from its neighbours) until a later
frame's depth confirms it (densify.check_guessed); tracking may leave guessed Gaussians out
(densify.hole_fill_tracked).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

PARAM_NAMES = ("means", "colors", "rotations", "logit_opacities", "log_scales")


@dataclass
class Gaussians:
    """Plain tensors handed to the renderer (a view of a GaussianMap, or hand-built in tests)."""

    means: torch.Tensor
    colors: torch.Tensor
    rotations: torch.Tensor
    logit_opacities: torch.Tensor
    log_scales: torch.Tensor

    def __len__(self) -> int:
        return self.means.shape[0]

    @property
    def isotropic(self) -> bool:
        return self.log_scales.shape[-1] == 1

    def fields(self) -> tuple[torch.Tensor, ...]:
        return tuple(getattr(self, n) for n in PARAM_NAMES)

    def select(self, keep: torch.Tensor) -> "Gaussians":
        """The Gaussians where `keep` (a bool mask or indices) selects."""
        return Gaussians(*(t[keep] for t in self.fields()))

    @classmethod
    def from_arrays(cls, arrays, device="cpu", dtype=torch.float32) -> "Gaussians":
        """Renderer input from map arrays (the GaussianMap.to_numpy() layout; never written to)."""
        return cls(*(torch.as_tensor(np.array(arrays[n], dtype=np.float32 if dtype == torch.float32 else None),
                                     dtype=dtype, device=device) for n in PARAM_NAMES))

    def to_arrays(self) -> dict[str, np.ndarray]:
        """numpy arrays of the fields (CPU tensors: views sharing their memory, not copies)."""
        return {n: t.detach().cpu().numpy() for n, t in zip(PARAM_NAMES, self.fields())}


class GaussianMap:
    """The optimisable Gaussian map. Append and prune keep an Adam optimiser's state aligned."""

    def __init__(self, means, colors, rotations, logit_opacities, log_scales, birth_frame, guessed=None):
        self.params = {
            name: torch.nn.Parameter(t.detach().clone().contiguous())
            for name, t in zip(PARAM_NAMES, (means, colors, rotations, logit_opacities, log_scales))
        }
        self.birth_frame = torch.as_tensor(birth_frame, dtype=torch.int64).clone()
        self.guessed = torch.zeros(len(self.birth_frame), dtype=torch.bool) if guessed is None \
            else torch.as_tensor(guessed, dtype=torch.bool).clone().reshape(-1)

    # ------------------------------------------------------------------ construction
    @classmethod
    def empty(cls, isotropic: bool = True, device="cpu", dtype=torch.float32) -> "GaussianMap":
        z = lambda *s: torch.zeros(*s, device=device, dtype=dtype)  # noqa: E731
        return cls(z(0, 3), z(0, 3), z(0, 4), z(0), z(0, 1 if isotropic else 3),
                   torch.zeros(0, dtype=torch.int64))

    @classmethod
    def from_points(cls, points, colors, radii, frame_index: int, isotropic: bool = True,
                    opacity: float = 0.5, device="cpu", dtype=torch.float32, guessed=None) -> "GaussianMap":
        """New Gaussians at world `points` with `colors` and radius `radii` (metres), identity rotation
        (`guessed`: N bools, the Gaussians whose depth was guessed; None: none)."""
        pts = torch.as_tensor(np.asarray(points), dtype=dtype, device=device).reshape(-1, 3)
        n = pts.shape[0]
        col = torch.as_tensor(np.asarray(colors), dtype=dtype, device=device).reshape(n, 3)
        log_r = torch.log(torch.as_tensor(np.asarray(radii), dtype=dtype, device=device).reshape(n, 1))
        rot = torch.zeros(n, 4, dtype=dtype, device=device)
        rot[:, 0] = 1.0
        logit = torch.full((n,), float(np.log(opacity / (1.0 - opacity))), dtype=dtype, device=device)
        scales = log_r if isotropic else log_r.expand(n, 3)
        return cls(pts, col, rot, logit, scales, torch.full((n,), int(frame_index), dtype=torch.int64),
                   None if guessed is None else torch.as_tensor(np.asarray(guessed), dtype=torch.bool).reshape(n))

    # ------------------------------------------------------------------ access
    def __len__(self) -> int:
        return self.params["means"].shape[0]

    def __getattr__(self, name):
        params = self.__dict__.get("params")
        if params is not None and name in params:
            return params[name]
        raise AttributeError(name)

    @property
    def isotropic(self) -> bool:
        return self.params["log_scales"].shape[-1] == 1

    @property
    def device(self):
        return self.params["means"].device

    @property
    def dtype(self):
        return self.params["means"].dtype

    def tensors(self, detach: bool = False) -> Gaussians:
        """The parameters as renderer input; `detach=True` for tracking (only the pose moves)."""
        get = (lambda t: t.detach()) if detach else (lambda t: t)
        return Gaussians(*(get(self.params[n]) for n in PARAM_NAMES))

    def opacities(self) -> torch.Tensor:
        return torch.sigmoid(self.params["logit_opacities"])

    def scales(self) -> torch.Tensor:
        """N x 3 activated scales (isotropic values tiled)."""
        return torch.exp(self.params["log_scales"]).expand(len(self), 3)

    def param_groups(self, lrs: dict) -> list[dict]:
        """Adam parameter groups, one per parameter with its own learning rate."""
        return [{"params": [self.params[n]], "lr": float(lrs[n]), "name": n} for n in PARAM_NAMES]

    def adam(self, lrs: dict) -> torch.optim.Adam:
        """Adam over the parameters (eps 1e-15, as 3DGS), torch's fused kernel where it has one
        (CPU since torch 2.4: 4x faster a step on 70k Gaussians than the per-tensor loop)."""
        try:
            return torch.optim.Adam(self.param_groups(lrs), eps=1e-15, fused=True)
        except (RuntimeError, TypeError):
            return torch.optim.Adam(self.param_groups(lrs), eps=1e-15)

    def anisotropic(self) -> "GaussianMap":
        """A copy with three scales per Gaussian (an isotropic one's tiled: the same Gaussians)."""
        n = len(self)
        values = [self.params[name].detach() for name in PARAM_NAMES]
        values[PARAM_NAMES.index("log_scales")] = values[PARAM_NAMES.index("log_scales")].expand(n, 3)
        return GaussianMap(*values, self.birth_frame, self.guessed)

    # ------------------------------------------------------------------ editing
    def append(self, other: "GaussianMap", optimizer: torch.optim.Optimizer | None = None) -> None:
        """Add `other`'s Gaussians; zero Adam moments are appended for them if an optimiser is given."""
        if len(other) == 0:
            return
        for name in PARAM_NAMES:
            extra = other.params[name].detach().to(self.device, self.dtype)
            self._replace(name, torch.cat([self.params[name].detach(), extra]), optimizer,
                          lambda s: torch.cat([s, torch.zeros_like(extra)]))
        self.birth_frame = torch.cat([self.birth_frame, other.birth_frame])
        self.guessed = torch.cat([self.guessed, other.guessed])

    def prune(self, keep: torch.Tensor, optimizer: torch.optim.Optimizer | None = None) -> int:
        """Keep only Gaussians where `keep` is True; returns how many were removed."""
        keep = keep.to(self.device)
        removed = int((~keep).sum())
        if removed == 0:
            return 0
        for name in PARAM_NAMES:
            self._replace(name, self.params[name].detach()[keep], optimizer, lambda s: s[keep])
        self.birth_frame = self.birth_frame[keep.cpu()]
        self.guessed = self.guessed[keep.cpu()]
        return removed

    def _replace(self, name, value, optimizer, edit_state) -> None:
        old = self.params[name]
        new = torch.nn.Parameter(value.contiguous())
        if optimizer is not None:
            for group in optimizer.param_groups:
                if group["params"][0] is old:
                    state = optimizer.state.pop(old, None)
                    if state:
                        for key in ("exp_avg", "exp_avg_sq"):
                            state[key] = edit_state(state[key]).contiguous()
                        optimizer.state[new] = state
                    group["params"][0] = new
        self.params[name] = new

    # ------------------------------------------------------------------ serialisation
    def to_numpy(self) -> dict[str, np.ndarray]:
        """Copies of the parameters and birth frames (and `guessed` where any is) as numpy arrays."""
        out = {n: a.copy() for n, a in self.tensors(detach=True).to_arrays().items()}
        out["birth_frame"] = self.birth_frame.cpu().numpy().copy()
        if bool(self.guessed.any()):
            out["guessed"] = self.guessed.cpu().numpy().copy()
        return out

    @classmethod
    def from_numpy(cls, arrays: dict, device="cpu", dtype=torch.float32) -> "GaussianMap":
        t = lambda a: torch.as_tensor(np.asarray(a), dtype=dtype, device=device)  # noqa: E731
        guessed = arrays.get("guessed")
        return cls(*(t(arrays[n]) for n in PARAM_NAMES), torch.as_tensor(arrays["birth_frame"]),
                   None if guessed is None else torch.as_tensor(np.asarray(guessed)))
