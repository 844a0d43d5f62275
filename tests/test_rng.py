"""Tests of the NumPy Philox4x32-10 (warpe_cl/rng.py) and of the draw layout of docs/walk.md §2."""
from fractions import Fraction

import numpy as np
import pytest

from warpe_cl.rng import PhotonStream, philox4x32, photon_draws, uniform_from_uint32

# Published Random123 known-answer vectors (kat_vectors, "philox4x32 10"):
# counter (4 words), key (2 words), expected output (4 words).
KNOWN_ANSWERS = [
    ((0x00000000, 0x00000000, 0x00000000, 0x00000000), (0x00000000, 0x00000000),
     (0x6627E8D5, 0xE169C58D, 0xBC57AC4C, 0x9B00DBD8)),
    ((0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF, 0xFFFFFFFF), (0xFFFFFFFF, 0xFFFFFFFF),
     (0x408F276D, 0x41C83B0E, 0xA20BC7C6, 0x6D5451FD)),
    ((0x243F6A88, 0x85A308D3, 0x13198A2E, 0x03707344), (0xA4093822, 0x299F31D0),
     (0xD16CFE09, 0x94FDCCEB, 0x5001E420, 0x24126EA1)),
]


@pytest.mark.parametrize("counter, key, expected", KNOWN_ANSWERS)
def test_known_answer_vectors(counter, key, expected):
    out = philox4x32(np.array(counter, dtype=np.uint32), np.array(key, dtype=np.uint32))
    assert out.dtype == np.uint32
    assert [int(w) for w in out] == list(expected)


def test_known_answer_vectors_vectorised_and_broadcast():
    counters = np.array([c for c, _, _ in KNOWN_ANSWERS], dtype=np.uint32)
    keys = np.array([k for _, k, _ in KNOWN_ANSWERS], dtype=np.uint32)
    expected = np.array([e for _, _, e in KNOWN_ANSWERS], dtype=np.uint32)
    np.testing.assert_array_equal(philox4x32(counters, keys), expected)
    # one key broadcast over several counters
    shared_key = np.zeros(2, dtype=np.uint32)
    out = philox4x32(np.zeros((3, 4), dtype=np.uint32), shared_key)
    np.testing.assert_array_equal(out, np.tile(expected[0], (3, 1)))


def test_rejects_words_wider_than_32_bits():
    with pytest.raises(ValueError):
        philox4x32([2 ** 32, 0, 0, 0], [0, 0])


# ------------------------------------------------------------------------------------------
# Uniform conversion
# ------------------------------------------------------------------------------------------

EDGE_WORDS = np.array([0, 1, 2, 3, 2 ** 24 - 1, 2 ** 24, 2 ** 24 + 1, 2 ** 24 + 3, 2 ** 31,
                       2 ** 32 - 257, 2 ** 32 - 256, 2 ** 32 - 129, 2 ** 32 - 128,
                       2 ** 32 - 127, 2 ** 32 - 2, 2 ** 32 - 1], dtype=np.uint32)


def _random_words(count=100_000):
    return np.random.default_rng(12345).integers(0, 2 ** 32, size=count, dtype=np.uint32)


def test_double_uniform_is_the_exact_formula():
    words = np.concatenate([EDGE_WORDS, _random_words(2000)])
    uniforms = uniform_from_uint32(words, "double")
    assert uniforms.dtype == np.float64
    for word, value in zip(words.tolist(), uniforms.tolist()):
        assert Fraction(value) == (Fraction(word) + Fraction(1, 2)) / 2 ** 32
    assert uniforms.min() > 0.0 and uniforms.max() < 1.0


def test_single_uniform_matches_a_direct_float32_computation():
    # Direct route: float(x) is exact; np.float32(...) rounds it once to nearest even.
    # float32(x) * 2^-32 + 2^-33 spans at most 33 significant bits, so it is exact in double,
    # and one final rounding to float32 is the correctly rounded float sum.
    words = np.concatenate([EDGE_WORDS, _random_words()])
    as_float = np.array([np.float32(float(w)) for w in words.tolist()], dtype=np.float32)
    exact_sum = as_float.astype(np.float64) * 2.0 ** -32 + 2.0 ** -33
    direct = exact_sum.astype(np.float32).astype(np.float64)
    np.testing.assert_array_equal(uniform_from_uint32(words, "single"), direct)


def test_single_uniform_range_and_rounding_to_one():
    uniforms = uniform_from_uint32(EDGE_WORDS, "single")
    assert np.all(uniforms > 0.0) and np.all(uniforms <= 1.0)
    assert uniforms[0] == 2.0 ** -33  # x = 0
    by_word = dict(zip(EDGE_WORDS.tolist(), uniforms.tolist()))
    # Spacing of float32 just below 2^32 is 256: 2^32 - 128 is a tie that rounds (to even)
    # up to 2^32, and 2^32 * 2^-32 + 2^-33 rounds back to 1.0f.
    assert by_word[2 ** 32 - 1] == 1.0
    assert by_word[2 ** 32 - 128] == 1.0
    assert by_word[2 ** 32 - 129] < 1.0
    random_uniforms = uniform_from_uint32(_random_words(), "single")
    assert np.all(random_uniforms > 0.0) and np.all(random_uniforms <= 1.0)


def test_unknown_precision_is_rejected():
    with pytest.raises(ValueError):
        uniform_from_uint32([1], "half")
    with pytest.raises(ValueError):
        PhotonStream(1, 0, 0, precision="half")


# ------------------------------------------------------------------------------------------
# Draw layout (walk.md §2) and streams
# ------------------------------------------------------------------------------------------

@pytest.mark.parametrize("photon", [0, 5, 2 ** 32 - 1, 2 ** 32 + 7, 3 * 2 ** 40 + 11])
def test_photon_draws_follow_the_counter_layout(photon):
    seed, scenario = 2024, 3
    draws = photon_draws(seed, scenario, photon, 10)
    for j in range(10):
        counter = [j // 4, photon % 2 ** 32, photon // 2 ** 32, 0]
        word = philox4x32(np.array(counter, dtype=np.uint64), [seed, scenario])[j % 4]
        assert draws[j] == (int(word) + 0.5) * 2.0 ** -32


@pytest.mark.parametrize("precision", ["double", "single"])
def test_photon_stream_equals_photon_draws(precision):
    for photon in (0, 1, 999, 2 ** 33 + 1):
        stream = PhotonStream(7, 11, photon, precision=precision)
        # 1000 draws cross several chunk extensions
        drawn = [stream.uniform() for _ in range(1000)]
        assert stream.count == 1000
        np.testing.assert_array_equal(drawn, photon_draws(7, 11, photon, 1000, precision))


def test_batched_streams_equal_single_streams():
    streams = PhotonStream.many(5, 2, first_photon=100, photons=20)
    for offset, stream in enumerate(streams):
        assert stream.photon == 100 + offset
        drawn = [stream.uniform() for _ in range(150)]  # past the prefetched 64 draws
        np.testing.assert_array_equal(drawn, photon_draws(5, 2, 100 + offset, 150))


def test_different_photons_and_keys_give_different_streams():
    reference = photon_draws(1, 0, 0, 64)
    others = [photon_draws(1, 0, 1, 64),          # next photon
              photon_draws(1, 0, 2 ** 32, 64),    # photon_hi word
              photon_draws(2, 0, 0, 64),          # seed
              photon_draws(1, 1, 0, 64)]          # scenario
    for other in others:
        assert not np.any(other == reference)
    # and the four words of a block differ from each other
    assert len(set(reference[:4].tolist())) == 4


def test_key_and_photon_range_are_checked():
    with pytest.raises(ValueError):
        PhotonStream(2 ** 32, 0, 0)
    with pytest.raises(ValueError):
        photon_draws(1, -1, 0, 4)
    with pytest.raises(ValueError):
        PhotonStream(1, 0, 2 ** 64)
