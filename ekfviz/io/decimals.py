"""Plain decimals read in one go: a block of tokens such as ``-12.3508`` as numpy reads
integers, each scaled by its power of ten.

A token of at most 15 digits with no exponent is m / 10^k, with the integer m written
by its digits and k its count of decimals. Both are exact in float64 (|m| < 10^15 <
2^53, k <= 15 < 22), so the one division is rounded once, correctly, and gives the bits
``float()`` gives the token (Clinger's fast path). numpy reads the integers of the whole
block in C; the rest is arithmetic on the block's bytes. Any other token (an exponent,
more digits, a sign or a point out of place) leaves the block to ``float()``.
"""

from __future__ import annotations

import numpy as np

from ekfviz.core.types import BoolArray, ByteArray, FloatArray, IntArray

MAX_DIGITS = 15  # digits of a token read here: its integer stays exact in float64
# 10^k for k <= MAX_DIGITS, each exact as written
_POWERS_OF_TEN = np.array([10.0**k for k in range(MAX_DIGITS + 1)])


def token_bounds(text: ByteArray) -> tuple[IntArray, IntArray, IntArray]:
    """Where each token of ``text`` (bytes; tokens parted by spaces, tabs and LF)
    starts and ends (its last byte), and the line (0-based) each lies on."""
    line_end = text == 0x0A
    gap = line_end | (text == 0x20) | (text == 0x09)
    first = ~gap
    first[1:] &= gap[:-1]
    last = ~gap
    last[:-1] &= gap[1:]
    starts = np.flatnonzero(first)
    return starts, np.flatnonzero(last), np.searchsorted(np.flatnonzero(line_end), starts)


def plain_decimals(
    joined: bytes, text: ByteArray, starts: IntArray, ends: IntArray
) -> tuple[FloatArray, BoolArray] | None:
    """The values of the tokens of ``joined`` (its bytes ``text``, tokens from
    ``starts`` to ``ends``) and whether each is digits alone, where every token is
    ``[+-]digits[.digits]`` (either side of the point may be empty, not both) of at most
    :data:`MAX_DIGITS` digits; else None."""
    if not len(starts):
        return np.zeros(0), np.zeros(0, dtype=bool)
    if ((text == 0x65) | (text == 0x45)).any():  # an exponent: float()'s
        return None
    signs = np.flatnonzero((text == 0x2B) | (text == 0x2D))
    token_of_sign = np.searchsorted(starts, signs, side="right") - 1
    if not np.array_equal(starts[token_of_sign], signs):  # a sign inside a token
        return None
    points = np.flatnonzero(text == 0x2E)
    token_of_point = np.searchsorted(starts, points, side="right") - 1
    if (np.diff(token_of_point) == 0).any():  # two points in one token
        return None
    signed = np.zeros(len(starts), dtype=bool)
    signed[token_of_sign] = True
    pointed = np.zeros(len(starts), dtype=bool)
    pointed[token_of_point] = True
    digits = ends - starts + 1 - signed - pointed
    if digits.min() < 1 or digits.max() > MAX_DIGITS:
        return None
    whole = _integers(joined.replace(b".", b""), len(starts))
    if whole is None:
        return None
    decimals = np.zeros(len(starts), dtype=np.int64)
    decimals[token_of_point] = ends[token_of_point] - points
    values = whole / _POWERS_OF_TEN[decimals]
    negative_zero = (whole == 0) & (text[starts] == 0x2D)
    values[negative_zero] = -0.0
    return values, ~(signed | pointed)


def _integers(joined: bytes, count: int) -> IntArray | None:
    """The ``count`` integers of ``joined`` (checked tokens of digits with a sign at
    most, parted by whitespace), or None where numpy reads another count.

    The tokens are checked first because numpy stops at the first it cannot read, with a
    warning; a filter of warnings is not set here, as it would hold for every thread.
    """
    try:
        whole = np.fromstring(joined, dtype=np.int64, sep=" ")
    except ValueError:
        return None
    return whole if len(whole) == count else None
