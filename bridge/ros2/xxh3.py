"""XXH3-128 (seed 0, default secret): how rmw_zenoh makes an entity's GID of its token.

A liveliness token's 16-byte GID is its XXH3-128, so the GID in our attachments is the
one every ROS 2 node computes for our publisher from its token.

Only inputs longer than 16 bytes (a token is always much longer); checked against
xxHash's own sanity-check vectors.
"""

from __future__ import annotations

import struct

_M64 = (1 << 64) - 1
PRIME32_1, PRIME32_2, PRIME32_3 = 0x9E3779B1, 0x85EBCA77, 0xC2B2AE3D
PRIME64_1, PRIME64_2, PRIME64_3 = 0x9E3779B185EBCA87, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9
PRIME64_4, PRIME64_5 = 0x85EBCA77C2B2AE63, 0x27D4EB2F165667C5
_MX1 = 0x165667919E3779F9
SECRET = bytes.fromhex(
    "b8fe6c3923a44bbe7c01812cf721ad1cded46de9839097db7240a4a4b7b3671f"
    "cb79e64eccc0e578825ad07dccff7221b8084674f743248ee03590e6813a264c"
    "3c2852bb91c300cb88d0658b1b532ea371644897a20df94e3819ef46a9deacd8"
    "a8fa763fe39c343ff9dcbbc7c70b4f1d8a51e04bcdb45931c89f7ec9d9787364"
    "eac5ac8334d3ebc3c581a0fffa1363eb170ddd51b7f0da49d316552629d4689e"
    "2b16be587d47a1fc8ff8b8d17ad031ce45cb3a8f95160428afd7fbcabb4b407e")
_STRIPE = 64
_BLOCK = _STRIPE * ((len(SECRET) - _STRIPE) // 8)


def _u64(data: bytes, at: int) -> int:
    return int.from_bytes(data[at:at + 8], "little")


def _fold(a: int, b: int) -> int:
    product = (a & _M64) * (b & _M64)
    return (product & _M64) ^ (product >> 64)


def _avalanche(h: int) -> int:
    h ^= h >> 37
    h = (h * _MX1) & _M64
    return h ^ (h >> 32)


def _mix16(data: bytes, at: int, secret_at: int) -> int:
    return _fold(_u64(data, at) ^ _u64(SECRET, secret_at),
                 _u64(data, at + 8) ^ _u64(SECRET, secret_at + 8))


def _mix32(low: int, high: int, data: bytes, first: int, second: int,
           secret_at: int) -> tuple[int, int]:
    low = ((low + _mix16(data, first, secret_at)) & _M64) \
        ^ ((_u64(data, second) + _u64(data, second + 8)) & _M64)
    high = ((high + _mix16(data, second, secret_at + 16)) & _M64) \
        ^ ((_u64(data, first) + _u64(data, first + 8)) & _M64)
    return low, high


def _finish(low: int, high: int, n: int) -> tuple[int, int]:
    h_low = (low + high) & _M64
    h_high = (low * PRIME64_1 + high * PRIME64_4 + n * PRIME64_2) & _M64
    return _avalanche(h_low), (-_avalanche(h_high)) & _M64


def _mid(data: bytes) -> tuple[int, int]:
    """17 to 240 bytes."""
    n = len(data)
    low, high = (n * PRIME64_1) & _M64, 0
    if n <= 128:
        for i in range((n - 1) // 32, -1, -1):
            low, high = _mix32(low, high, data, 16 * i, n - 16 * (i + 1), 32 * i)
        return _finish(low, high, n)
    for i in range(4):
        low, high = _mix32(low, high, data, 32 * i, 32 * i + 16, 32 * i)
    low, high = _avalanche(low), _avalanche(high)
    for i in range(4, n // 32):
        low, high = _mix32(low, high, data, 32 * i, 32 * i + 16, 3 + 32 * (i - 4))
    low, high = _mix32(low, high, data, n - 16, n - 32, 136 - 17 - 16)
    return _finish(low, high, n)


def _stripe(acc: list[int], data: bytes, at: int, secret_at: int) -> None:
    for lane in range(8):
        value = _u64(data, at + 8 * lane)
        key = value ^ _u64(SECRET, secret_at + 8 * lane)
        acc[lane ^ 1] = (acc[lane ^ 1] + value) & _M64
        acc[lane] = (acc[lane] + (key & 0xFFFFFFFF) * (key >> 32)) & _M64


def _merge(acc: list[int], secret_at: int, start: int) -> int:
    total = start
    for i in range(4):
        total += _fold(acc[2 * i] ^ _u64(SECRET, secret_at + 16 * i),
                       acc[2 * i + 1] ^ _u64(SECRET, secret_at + 16 * i + 8))
    return _avalanche(total & _M64)


def _long(data: bytes) -> tuple[int, int]:
    """More than 240 bytes: 64-byte stripes into eight accumulators."""
    n = len(data)
    acc = [PRIME32_3, PRIME64_1, PRIME64_2, PRIME64_3, PRIME64_4, PRIME32_2, PRIME64_5,
           PRIME32_1]
    blocks = (n - 1) // _BLOCK
    for b in range(blocks):
        for s in range(_BLOCK // _STRIPE):
            _stripe(acc, data, b * _BLOCK + s * _STRIPE, s * 8)
        for lane in range(8):
            a = acc[lane]
            a ^= a >> 47
            a ^= _u64(SECRET, len(SECRET) - _STRIPE + 8 * lane)
            acc[lane] = (a * PRIME32_1) & _M64
    for s in range(((n - 1) - blocks * _BLOCK) // _STRIPE):
        _stripe(acc, data, blocks * _BLOCK + s * _STRIPE, s * 8)
    _stripe(acc, data, n - _STRIPE, len(SECRET) - _STRIPE - 7)
    return (_merge(acc, 11, (n * PRIME64_1) & _M64),
            _merge(acc, len(SECRET) - 64 - 11, ~(n * PRIME64_2) & _M64))


def xxh3_128(data: bytes) -> tuple[int, int]:
    """(low64, high64) of XXH3-128 with seed 0; ``data`` longer than 16 bytes."""
    if len(data) <= 16:
        raise ValueError("xxh3_128 here hashes more than 16 bytes (a liveliness token)")
    return _mid(data) if len(data) <= 240 else _long(data)


def xxh3_128_bytes(data: bytes) -> bytes:
    """The hash as rmw_zenoh stores a GID: low64 then high64, each little-endian."""
    return struct.pack("<QQ", *xxh3_128(data))
