"""LZF (Marc Lehmann's liblzf, the compression of PCL's ``DATA binary_compressed`` PCD files) in numba kernels.

The stream is a sequence of runs, each opened by a control byte ``c``: ``c < 32`` copies the next ``c + 1`` bytes;
otherwise it copies ``len + 2`` bytes from ``off + 1`` bytes back in the output, where ``len = c >> 5`` (7: plus the
next byte) and ``off = (c & 31) << 8`` plus the byte after. Back-references may overlap the bytes they write.
"""

from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ["lzf_decompress", "lzf_compress", "compressed_bound"]

#: :func:`lzf_decompress`'s codes for a stream that does not decode.
TRUNCATED, OVERFLOW, BAD_REFERENCE = -1, -2, -3

_HASH_BITS = 14
_MAX_OFF = 1 << 13
_MAX_REF = (1 << 8) + (1 << 3)  # the longest back-reference: 7 + 255 + 2 bytes


@nb.njit(cache=True, nogil=True)
def lzf_decompress(src, out):  # pragma: no cover - JIT
    """Decode ``src`` (uint8) into ``out`` (uint8); the number of bytes written, or a negative code: the input
    ends inside a run (:data:`TRUNCATED`), the output would pass ``out``'s end (:data:`OVERFLOW`), a reference
    points before the output's start (:data:`BAD_REFERENCE`)."""
    ip, op = 0, 0
    n_in, n_out = src.shape[0], out.shape[0]
    while ip < n_in:
        ctrl = np.int64(src[ip])
        ip += 1
        if ctrl < 32:
            length = ctrl + 1
            if ip + length > n_in:
                return TRUNCATED
            if op + length > n_out:
                return OVERFLOW
            for k in range(length):
                out[op + k] = src[ip + k]
            ip += length
            op += length
        else:
            length = ctrl >> 5
            if length == 7:
                if ip >= n_in:
                    return TRUNCATED
                length += np.int64(src[ip])
                ip += 1
            if ip >= n_in:
                return TRUNCATED
            ref = op - ((ctrl & 31) << 8) - 1 - np.int64(src[ip])
            ip += 1
            length += 2
            if ref < 0:
                return BAD_REFERENCE
            if op + length > n_out:
                return OVERFLOW
            for k in range(length):  # byte by byte: the reference may overlap what it writes
                out[op + k] = out[ref + k]
            op += length
    return op


def compressed_bound(n: int) -> int:
    """The most bytes :func:`lzf_compress` writes for ``n`` input bytes (all literals: one control byte per 32)."""
    return int(n) + int(n) // 32 + 2


@nb.njit(cache=True, nogil=True)
def lzf_compress(src, out):  # pragma: no cover - JIT
    """Encode ``src`` (uint8) into ``out`` (uint8, at least :func:`compressed_bound` bytes); the bytes written.
    Back-references come from a hash table of the last position of each 3-byte sequence (liblzf's scheme)."""
    n = src.shape[0]
    table = np.full(1 << _HASH_BITS, -1, dtype=np.int64)
    ip, op = 0, 1
    lit, lit_at = 0, 0  # the open literal run: its length and its control byte's position
    while ip < n:
        if ip + 2 < n:
            h = ((np.int64(src[ip]) << 16) | (np.int64(src[ip + 1]) << 8) | np.int64(src[ip + 2]))
            h = ((h * 2654435761) & 0xFFFFFFFF) >> (32 - _HASH_BITS)
            ref = table[h]
            table[h] = ip
            off = ip - ref - 1
            if (ref >= 0 and off < _MAX_OFF and src[ref] == src[ip] and src[ref + 1] == src[ip + 1]
                    and src[ref + 2] == src[ip + 2]):
                longest = min(_MAX_REF, n - ip)
                length = 3
                while length < longest and src[ref + length] == src[ip + length]:
                    length += 1
                if lit > 0:
                    out[lit_at] = lit - 1
                else:
                    op -= 1  # no literal before: drop the control byte kept for one
                code = length - 2
                if code < 7:
                    out[op] = (code << 5) + (off >> 8)
                    op += 1
                else:
                    out[op] = (7 << 5) + (off >> 8)
                    out[op + 1] = code - 7
                    op += 2
                out[op] = off & 255
                op += 1
                ip += length
                lit, lit_at = 0, op
                op += 1
                continue
        out[op] = src[ip]
        op += 1
        ip += 1
        lit += 1
        if lit == 32:
            out[lit_at] = 31
            lit, lit_at = 0, op
            op += 1
    if lit > 0:
        out[lit_at] = lit - 1
    else:
        op -= 1
    return op
