"""Plain decimals read in one go give float()'s bits, or leave the block to float()."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ekfviz.io.decimals import MAX_DIGITS, plain_decimals, token_bounds

# [+-]digits[.digits] with at most 15 digits, a side of the point possibly empty
_PLAIN = st.from_regex(r"\A[-+]?([0-9]{1,15}|[0-9]{1,8}\.[0-9]{0,7}|[0-9]{0,7}\.[0-9]{1,8})\Z")


def _read(tokens: list[list[str]], gap: str = " ") -> tuple[np.ndarray, np.ndarray] | None:
    joined = "\n".join(gap.join(line) for line in tokens).encode()
    text = np.frombuffer(joined, dtype=np.uint8)
    starts, ends, _ = token_bounds(text)
    return plain_decimals(joined, text, starts, ends)


_PLAIN_LINES = st.lists(st.lists(_PLAIN, min_size=1, max_size=6), min_size=1, max_size=6)
_GAPS = st.sampled_from([" ", "\t", " \t "])


@settings(max_examples=40, deadline=None)
@given(_PLAIN_LINES, _GAPS)
def test_plain_decimals_give_the_bits_float_gives(tokens: list[list[str]], gap: str) -> None:
    """See :func:`_plain_decimals_give_the_bits_float_gives`."""
    _plain_decimals_give_the_bits_float_gives(tokens, gap)


@pytest.mark.slow
@settings(max_examples=400, deadline=None)
@given(_PLAIN_LINES, _GAPS)
def test_plain_decimals_give_the_bits_float_gives_on_many_examples(
    tokens: list[list[str]], gap: str
) -> None:
    """See :func:`_plain_decimals_give_the_bits_float_gives`."""
    _plain_decimals_give_the_bits_float_gives(tokens, gap)


def _plain_decimals_give_the_bits_float_gives(tokens: list[list[str]], gap: str) -> None:
    """Every plain decimal is read here (none is left to float()), to float()'s bits,
    and digits alone are told apart."""
    read = _read(tokens, gap)
    assert read is not None
    values, digits = read
    flat = [t for line in tokens for t in line]
    expected = np.array([float(t) for t in flat])
    np.testing.assert_array_equal(values.view(np.int64), expected.view(np.int64))
    assert digits.tolist() == [t.isdigit() for t in flat]


def test_known_answers_keep_signs_zeros_and_fifteen_digits() -> None:
    """A negative zero keeps its sign; leading zeros, a bare point on either side, a
    plus sign, and 15 digits read as float() reads them."""
    tokens = ["-0.0000", "+0", "007", "5.", ".5", "-.25", "0.1", "123456789012345"]
    tokens += ["9.99999999999999", "-0.3"]
    read = _read([tokens])
    assert read is not None
    values = read[0]
    assert np.signbit(values[0]) and values[0] == 0.0
    assert not np.signbit(values[1])
    assert values.tolist() == [float(t) for t in tokens]


@pytest.mark.parametrize(
    "token",
    ["1e5", "2E-3", "1" * (MAX_DIGITS + 1), "1.2.3", "-", "+", ".", "-.", "+-1", "1-2", "3+"],
)
def test_anything_else_is_left_to_float(token: str) -> None:
    """An exponent, a 16th digit, a second point, a sign alone or out of place: None,
    the whole block then read by float() (or line by line, to name a bad token)."""
    assert _read([["1.5", token, "2"]]) is None


def test_an_empty_block_has_no_values() -> None:
    read = _read([[]])
    assert read is not None
    assert read[0].shape == (0,) and read[1].shape == (0,)
