"""The random numbers of one rendered sample, drawn in numpy without a tensor operation per number.

A sample's random numbers come from its own stream, seeded by ``(seed, index)`` alone, so a sample
is the same scene in whatever batch it is rendered. The stream is torch's CPU generator (mt19937
seeded with the low 32 bits of the seed, as ``torch.Generator().manual_seed`` seeds it) replayed
word for word with numpy's MT19937, and the words become numbers as torch makes them:

- ``uniform()``: ``torch.rand((), dtype=torch.float64)``: two words, 53 bits;
- ``uniform32(*shape)``: ``torch.rand(*shape)``: one word each, 24 bits;
- ``normal_uniforms(n)`` then :func:`box_muller`: ``torch.randn(n)`` (torch's ``normal_fill``:
  Box-Muller over blocks of 16 uniforms; the same words, float32 rounding of log / sin / cos
  aside). The words are drawn per sample; the arithmetic runs once for the batch, on its device;
- ``choice(weights)``: ``torch.multinomial(weights, 1)`` (argmax of weight / Exp(1) draws).

So the scenes rendered before the renderer was batched are the scenes rendered now (within float
rounding), and every rendered evaluation set keeps its frames. A scalar costs about a microsecond
of Python and no tensor operation: the renderer draws a sample's table of numbers here, then
renders the batch with tensor operations whose count does not grow with the batch.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

_BLOCK = 256  # words fetched at a time for scalar draws
_MASK53 = (1 << 53) - 1
_MASK24 = (1 << 24) - 1


class SampleDraws:
    """The random stream of one sample: torch's ``torch.Generator().manual_seed(seed)``, in numpy."""

    def __init__(self, seed: int):
        self.seed = int(seed)
        self._rs = np.random.RandomState(self.seed & 0xFFFFFFFF)  # mt19937's init_genrand, as torch seeds it
        self._words: list[int] = []  # fetched, not yet used (in stream order)
        self._next = 0

    def initial_seed(self) -> int:
        """The seed the stream started from (``torch.Generator.initial_seed``)."""
        return self.seed

    def _fetch(self, n: int) -> np.ndarray:
        return self._rs.randint(0, 2**32, size=n, dtype=np.uint32)  # the full range: mt19937's raw words

    def _word(self) -> int:
        if self._next == len(self._words):
            self._words, self._next = self._fetch(_BLOCK).tolist(), 0
        self._next += 1
        return self._words[self._next - 1]

    def words(self, n: int) -> np.ndarray:
        """The next ``n`` 32-bit words of the stream, (n,) uint32."""
        held = self._words[self._next : self._next + n]
        self._next += len(held)
        if len(held) == n:
            return np.asarray(held, np.uint32)
        return np.concatenate([np.asarray(held, np.uint32), self._fetch(n - len(held))])

    def uniform(self, lo: float = 0.0, hi: float = 1.0) -> float:
        """One float64 uniform in [lo, hi)."""
        hi_word = self._word()
        x = (((hi_word << 32) | self._word()) & _MASK53) * (1.0 / (1 << 53))
        return lo + (hi - lo) * x

    def uniform32(self, *shape: int) -> np.ndarray:
        """float32 uniforms in [0, 1) of ``shape``."""
        n = math.prod(shape)
        return ((self.words(n) & _MASK24).astype(np.float32) * np.float32(1.0 / (1 << 24))).reshape(shape)

    def normal_uniforms(self, n: int) -> np.ndarray:
        """The uniforms of ``torch.randn(n)``, (ceil(n / 16), 16) float32 blocks for
        :func:`box_muller` (n >= 16; where 16 does not divide n, the last block is 16 more)."""
        if n < 16:
            raise ValueError(f"torch draws normals in blocks of 16; {n} is too few")
        u = self.uniform32(n)[: n - n % 16].reshape(-1, 16)
        return np.concatenate([u, self.uniform32(1, 16)]) if n % 16 else u

    def choice(self, weights: list[float] | np.ndarray) -> int:
        """An index drawn with probability proportional to ``weights`` (torch.multinomial(w, 1))."""
        w = np.asarray(weights, np.float64)
        e = np.array([-math.log1p(-self.uniform()) for _ in w])  # Exp(1), one per category
        return int(np.argmax(w / e))


def box_muller(blocks: Tensor, n: int) -> Tensor:
    """Standard normals (..., n) from the uniforms (..., M, 16) of :meth:`SampleDraws.normal_uniforms`,
    as torch's normal_fill makes them: in a block, the first 8 pair with the last 8."""
    radius = torch.sqrt(-2.0 * torch.log(1.0 - blocks[..., :8]))
    theta = (2.0 * math.pi) * blocks[..., 8:]
    z = torch.cat([radius * torch.cos(theta), radius * torch.sin(theta)], -1).flatten(-2)
    return torch.cat([z[..., : n - 16], z[..., -16:]], -1) if n % 16 else z


def sample_draws(seed: int, index: int) -> SampleDraws:
    """The stream of sample ``index`` under ``seed`` (independent of the batch it is rendered in)."""
    return SampleDraws((seed * 1_000_003 + index * 7_919 + 12_345) % (2**63 - 1))


def to_device(values, device: torch.device, dtype: torch.dtype | None = None) -> Tensor:
    """Host numbers (a numpy array, a list or a CPU tensor) as a tensor on ``device``. On a GPU
    they go through pinned memory without waiting (the copy queues behind the GPU's work: no host
    sync); on the CPU the tensor may share the array's memory."""
    t = values if isinstance(values, Tensor) else torch.from_numpy(np.ascontiguousarray(values))
    t = t if dtype is None else t.to(dtype)
    return t.pin_memory().to(device, non_blocking=True) if device.type == "cuda" else t
