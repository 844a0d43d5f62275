"""NumPy Philox4x32-10, the counter-based generator of the walk (docs/walk.md §2).

This is a slow, exact copy of Random123's ``philox4x32`` (Salmon, Moraes, Dror & Shaw 2011,
"Parallel random numbers: as easy as 1, 2, 3", SC'11), written with NumPy integer arithmetic so
that the host can reproduce, bit for bit, every word the OpenCL kernels draw. It is pinned by the
published Random123 known-answer vectors (``tests/test_rng.py``).

How the walk uses it (docs/walk.md §2):

* the scenario key is 64 bits (:func:`warpe_cl.api.scenario_key`): key_lo = scenario mod 2**32,
  key_hi = scenario >> 32;
* key = (seed, key_lo), two uint32 words;
* counter = (block, photon_lo, photon_hi, key_hi) for photon p = photon_hi * 2**32 + photon_lo
  (key_hi = 0 for scenario keys below 2**32, the layout before 64-bit keys);
* draw j of photon p is word ``j % 4`` of block ``j // 4``; the walk takes one block per
  event (:meth:`PhotonStream.block`), so its k-th event uses block k;
* a word x becomes the uniform U = (x + 0.5) * 2**-32, in (0, 1) in double precision; the
  single-precision kernels evaluate ``(float)x * 0x1p-32f + 0x1p-33f`` instead, which can
  round to exactly 1.0f.

Examples
--------
>>> from warpe_cl.rng import philox4x32, photon_draws
>>> [f"{w:08x}" for w in philox4x32([0, 0, 0, 0], [0, 0])]
['6627e8d5', 'e169c58d', 'bc57ac4c', '9b00dbd8']
>>> stream = PhotonStream(seed=1, scenario=0, photon=7)
>>> first = [stream.uniform() for _ in range(5)]
>>> bool(np.array_equal(first, photon_draws(1, 0, 7, 5)))
True
"""
from __future__ import annotations

import numpy as np

__all__ = ["philox4x32", "uniform_from_uint32", "photon_draws", "PhotonStream",
           "PHILOX_MULTIPLIERS", "PHILOX_WEYL"]

#: Round multipliers of philox4x32 (Random123 ``PHILOX_M4x32_0``, ``PHILOX_M4x32_1``).
PHILOX_MULTIPLIERS = (0xD2511F53, 0xCD9E8D57)
#: Weyl-sequence key increments (Random123 ``PHILOX_W32_0``, ``PHILOX_W32_1``).
PHILOX_WEYL = (0x9E3779B9, 0xBB67AE85)

_MASK32 = np.uint64(0xFFFFFFFF)
_SHIFT32 = np.uint64(32)
_PRECISIONS = ("double", "single")


def _mulhilo32(multiplier: int, word: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Full 32x32 -> 64-bit product, split into (high word, low word), both uint64 < 2**32."""
    product = np.uint64(multiplier) * word.astype(np.uint64)  # < 2**64: exact in uint64
    return product >> _SHIFT32, product & _MASK32


def philox4x32(counter, key, rounds: int = 10) -> np.ndarray:
    """Random123 ``philox4x32_R``: four uint32 words from a counter and a key.

    Parameters
    ----------
    counter : array_like of uint32, shape (..., 4)
        Counter words (c0, c1, c2, c3).
    key : array_like of uint32, shape (..., 2)
        Key words (k0, k1); broadcast against ``counter``.
    rounds : int, optional
        Number of rounds R (10 for the walk).

    Returns
    -------
    numpy.ndarray of uint32, shape (..., 4)
        The output block.

    Notes
    -----
    One round (Random123 ``_philox4x32round``), with 64-bit products
    p0 = 0xD2511F53 * c0 and p1 = 0xCD9E8D57 * c2::

        (c0, c1, c2, c3) <- (hi(p1) ^ c1 ^ k0, lo(p1), hi(p0) ^ c3 ^ k1, lo(p0))

    Before every round but the first the key is bumped by the Weyl constants,
    k0 += 0x9E3779B9, k1 += 0xBB67AE85 (mod 2**32).
    """
    counter = np.asarray(counter, dtype=np.uint64)
    key = np.asarray(key, dtype=np.uint64)
    if counter.shape[-1:] != (4,):
        raise ValueError(f"counter must have shape (..., 4), got {counter.shape}")
    if key.shape[-1:] != (2,):
        raise ValueError(f"key must have shape (..., 2), got {key.shape}")
    if np.any(counter > _MASK32) or np.any(key > _MASK32):
        raise ValueError("counter and key words must be uint32 (0 .. 2**32 - 1)")
    # Work in uint64 holding 32-bit values; every result is masked back to 32 bits.
    c0, c1, c2, c3 = (counter[..., i] for i in range(4))
    k0, k1 = key[..., 0], key[..., 1]
    m0, m1 = PHILOX_MULTIPLIERS
    w0, w1 = np.uint64(PHILOX_WEYL[0]), np.uint64(PHILOX_WEYL[1])
    for round_index in range(rounds):
        if round_index > 0:
            k0 = (k0 + w0) & _MASK32
            k1 = (k1 + w1) & _MASK32
        hi0, lo0 = _mulhilo32(m0, c0)
        hi1, lo1 = _mulhilo32(m1, c2)
        c0, c1, c2, c3 = hi1 ^ c1 ^ k0, lo1, hi0 ^ c3 ^ k1, lo0
    c0, c1, c2, c3 = np.broadcast_arrays(c0, c1, c2, c3)
    return np.stack([c0, c1, c2, c3], axis=-1).astype(np.uint32)


def uniform_from_uint32(x, precision: str = "double") -> np.ndarray:
    """Turn Philox words into uniforms in (0, 1] as the kernels do (docs/walk.md §2).

    Parameters
    ----------
    x : array_like of uint32
        Philox output words.
    precision : {"double", "single"}
        ``"double"``: U = (x + 0.5) * 2**-32, exact in float64, strictly inside (0, 1).
        ``"single"``: the OpenCL float expression ``(float)x * 0x1p-32f + 0x1p-33f``
        evaluated step by step in float32 (x rounded to nearest even, an exact
        power-of-two product, then one rounded sum); U can be exactly 1.0.

    Returns
    -------
    numpy.ndarray of float64
        The uniforms (single-precision values widened exactly to float64).
    """
    x = np.asarray(x, dtype=np.uint32)
    if precision == "double":
        # x + 0.5 needs 33 significant bits and the scaling is a power of two: exact.
        return (x.astype(np.float64) + 0.5) * 2.0 ** -32
    if precision == "single":
        as_float = x.astype(np.float32)  # round to nearest even, like (float)x in OpenCL C
        scaled = as_float * np.float32(2.0 ** -32)  # exact (power of two, no underflow)
        # A contracted fma(as_float, 2^-32, 2^-33) gives the same value: the product is exact.
        return (scaled + np.float32(2.0 ** -33)).astype(np.float64)
    raise ValueError(f"precision must be one of {_PRECISIONS}, got {precision!r}")


def _photon_counters(photon: int, blocks: np.ndarray, key_hi: int = 0) -> np.ndarray:
    """Counters (block, photon_lo, photon_hi, key_hi) for one photon, shape (len(blocks), 4)."""
    photon = int(photon)
    if not 0 <= photon < 2 ** 64:
        raise ValueError(f"photon index must be in 0 .. 2**64 - 1, got {photon}")
    counters = np.zeros((len(blocks), 4), dtype=np.uint64)
    counters[:, 0] = blocks
    counters[:, 1] = photon & 0xFFFFFFFF
    counters[:, 2] = photon >> 32
    counters[:, 3] = key_hi
    return counters


def _walk_key(seed: int, scenario: int) -> np.ndarray:
    """Philox key (seed, key_lo) of the walk; key_hi (:func:`_key_hi`) goes in the counter."""
    if not 0 <= int(seed) < 2 ** 32:
        raise ValueError(f"seed must be a uint32 (0 .. 2**32 - 1), got {seed}")
    if not 0 <= int(scenario) < 2 ** 64:
        raise ValueError(f"scenario must be a uint64 (0 .. 2**64 - 1), got {scenario}")
    return np.array([int(seed), int(scenario) & 0xFFFFFFFF], dtype=np.uint64)


def _key_hi(scenario: int) -> int:
    return int(scenario) >> 32


def photon_draws(seed: int, scenario: int, photon: int, n_draws: int,
                 precision: str = "double") -> np.ndarray:
    """The first ``n_draws`` uniforms of one photon (docs/walk.md §2).

    Parameters
    ----------
    seed : int
        Key word (uint32).
    scenario : int
        Scenario key (uint64): low word in the key, high word in counter word 3.
    photon : int
        Photon index p (0 .. 2**64 - 1).
    n_draws : int
        Number of draws wanted.
    precision : {"double", "single"}
        Uniform conversion, see :func:`uniform_from_uint32`.

    Returns
    -------
    numpy.ndarray of float64, shape (n_draws,)
        Draw j is word ``j % 4`` of block ``j // 4``.
    """
    n_blocks = -(-int(n_draws) // 4)
    key = _walk_key(seed, scenario)
    counters = _photon_counters(photon, np.arange(n_blocks, dtype=np.uint64), _key_hi(scenario))
    words = philox4x32(counters, key).reshape(-1)[:n_draws]
    return uniform_from_uint32(words, precision)


class PhotonStream:
    """The uniform draws of one photon, one at a time (docs/walk.md §2).

    Blocks are generated vectorised in chunks (16 blocks = 64 draws first, then chunks as
    large as everything fetched so far), so a per-photon Python loop pays the NumPy cost
    rarely.

    Parameters
    ----------
    seed : int
        Key word (uint32).
    scenario : int
        Scenario key (uint64).
    photon : int
        Photon index p.
    precision : {"double", "single"}
        Uniform conversion, see :func:`uniform_from_uint32`.

    Attributes
    ----------
    count : int
        Draws consumed so far.
    """

    #: Blocks of the first chunk (4 draws each).
    FIRST_CHUNK_BLOCKS = 16

    def __init__(self, seed: int, scenario: int, photon: int, precision: str = "double"):
        if precision not in _PRECISIONS:
            raise ValueError(f"precision must be one of {_PRECISIONS}, got {precision!r}")
        self.seed = int(seed)
        self.scenario = int(scenario)
        self.photon = int(photon)
        self.precision = precision
        self.count = 0
        self._key = _walk_key(seed, scenario)
        _photon_counters(photon, np.zeros(0))  # validate the index now
        self._draws: list[float] = []

    @classmethod
    def many(cls, seed: int, scenario: int, first_photon: int, photons: int,
             precision: str = "double") -> list["PhotonStream"]:
        """Streams for photons ``first_photon .. first_photon + photons - 1``.

        Their first chunks are generated in one vectorised call, which is much faster than
        creating the streams one by one when most photons need only a few draws.
        """
        first = cls(seed, scenario, first_photon, precision)  # validates key and precision
        if photons <= 0:
            return []
        _photon_counters(first_photon + photons - 1, np.zeros(0))  # validates the last index
        streams = [first]
        for offset in range(1, photons):
            # Same fields as __init__, without repeating its checks for every photon.
            stream = cls.__new__(cls)
            stream.seed, stream.scenario, stream.precision = first.seed, first.scenario, precision
            stream.photon = first.photon + offset
            stream.count = 0
            stream._key = first._key
            streams.append(stream)
        n_blocks = cls.FIRST_CHUNK_BLOCKS
        photon_index = np.arange(photons, dtype=np.uint64) + np.uint64(first_photon)
        counters = np.zeros((photons, n_blocks, 4), dtype=np.uint64)
        counters[:, :, 0] = np.arange(n_blocks, dtype=np.uint64)[None, :]
        counters[:, :, 1] = (photon_index & _MASK32)[:, None]
        counters[:, :, 2] = (photon_index >> _SHIFT32)[:, None]
        counters[:, :, 3] = _key_hi(first.scenario)
        words = philox4x32(counters, first._key).reshape(photons, 4 * n_blocks)
        uniforms = uniform_from_uint32(words, precision).tolist()
        for stream, draws in zip(streams, uniforms):
            stream._draws = draws
        return streams

    def _extend(self) -> None:
        """Fetch the next chunk of blocks."""
        first_block = len(self._draws) // 4
        n_blocks = max(self.FIRST_CHUNK_BLOCKS, first_block)
        if first_block + n_blocks > 2 ** 32:
            raise OverflowError("photon stream exhausted its 2**32 blocks")
        counters = _photon_counters(
            self.photon, np.arange(first_block, first_block + n_blocks, dtype=np.uint64),
            _key_hi(self.scenario))
        words = philox4x32(counters, self._key).reshape(-1)
        self._draws.extend(uniform_from_uint32(words, self.precision).tolist())

    def uniform(self) -> float:
        """The next draw, a Python float in (0, 1] (in (0, 1) in double precision)."""
        index = self.count
        if index >= len(self._draws):
            self._extend()
        self.count = index + 1
        return self._draws[index]

    def block(self) -> tuple[float, float, float, float]:
        """The four uniforms of the next block (the walk's next event, docs/walk.md §2).

        Draws of the current block not yet taken by :meth:`uniform` are skipped: the walk uses
        block k for its k-th event, whatever number of its four words that event needs.

        Returns
        -------
        tuple of 4 floats in (0, 1]
        """
        start = -(-self.count // 4) * 4
        if start + 4 > len(self._draws):
            self._extend()
        self.count = start + 4
        return tuple(self._draws[start:start + 4])
