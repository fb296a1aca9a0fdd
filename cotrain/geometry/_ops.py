"""The few array operations whose numpy and torch spellings differ, chosen from the inputs' type.

The camera models and pose helpers are written once over arrays that are either numpy arrays (the
calibrator, float64, no torch installed) or torch tensors (the renderer and training, on the GPU,
with gradients). Everything both libraries spell alike (arithmetic, ``where``, ``sqrt``, ``sin``,
``stack``, ``ones_like``, indexing) is used through the module :func:`ops` returns; the rest is
here. torch is imported only when a tensor is given.
"""

from __future__ import annotations

from types import SimpleNamespace
from typing import Any

import numpy as np


def is_tensor(x: Any) -> bool:
    """True for a torch tensor (told from its type's module, so torch is not imported)."""
    return type(x).__module__.split(".")[0] == "torch"


def _np_norm(x, dim: int = -1, keepdim: bool = False):
    return np.linalg.norm(x, axis=dim, keepdims=keepdim)


def _np_sum(x, dim: int = -1, keepdim: bool = False):
    return np.sum(x, axis=dim, keepdims=keepdim)


def _np_split(x, n: int) -> list:
    return list(np.split(x, n, axis=-1))


def _np_eye(n: int, like):
    return np.eye(n, dtype=like.dtype)


def _np_gather(x, dim: int, index):
    return np.take_along_axis(x, index, axis=dim)


def _np_argmax(x, dim: int = -1, keepdim: bool = False):
    i = np.argmax(x, axis=dim)
    return np.expand_dims(i, dim) if keepdim else i


_NUMPY = SimpleNamespace(
    xp=np,
    cat=np.concatenate,
    split=_np_split,
    norm=_np_norm,
    sum=_np_sum,
    clamp=np.clip,
    clamp_min=np.maximum,
    atan2=np.arctan2,
    acos=np.arccos,
    eye=_np_eye,
    gather=_np_gather,
    argmax=_np_argmax,
    cross=lambda a, b: np.cross(a, b, axis=-1),
    copy=np.copy,
    float32=np.float32,
    pi=np.pi,
)

_TORCH: SimpleNamespace | None = None


def _torch_ops() -> SimpleNamespace:
    global _TORCH
    if _TORCH is None:
        import torch

        _TORCH = SimpleNamespace(
            xp=torch,
            cat=torch.cat,
            split=lambda x, n: list(x.split(1, dim=-1)),
            norm=lambda x, dim=-1, keepdim=False: x.norm(dim=dim, keepdim=keepdim),
            sum=lambda x, dim=-1, keepdim=False: x.sum(dim, keepdim=keepdim),
            clamp=torch.clamp,
            clamp_min=lambda x, lo: x.clamp_min(lo),
            atan2=torch.atan2,
            acos=torch.acos,
            eye=lambda n, like: torch.eye(n, dtype=like.dtype, device=like.device),
            gather=torch.gather,
            argmax=lambda x, dim=-1, keepdim=False: x.argmax(dim, keepdim=keepdim),
            cross=lambda a, b: torch.linalg.cross(a, b, dim=-1),
            copy=torch.clone,
            float32=torch.float32,
            pi=torch.pi,
        )
    return _TORCH


def ops(*xs: Any) -> SimpleNamespace:
    """The operations for ``xs``: torch's where any of them is a tensor, numpy's otherwise.
    ``.xp`` is the module itself (numpy or torch) for the functions both spell alike."""
    return _torch_ops() if any(is_tensor(x) for x in xs) else _NUMPY
