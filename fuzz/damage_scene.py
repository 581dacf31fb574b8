#!/usr/bin/env python3
"""Damage a .vxc scene file the way a buggy writer would: set 32-bit words of
one section payload and recompute that section's xxHash64 (its chunk hashes
and, in version 2 files, the directory hash), so the container checks pass and the damage reaches the validators (issue 15; the C++ sweep is
tests/test_scene_damage.cpp, README "Reliability").

    fuzz/damage_scene.py IN.vxc OUT.vxc SECTION WORD=VALUE [WORD=VALUE ...]
    fuzz/damage_scene.py IN.vxc --list            # sections and their sizes

WORD is a word index into the section payload, VALUE a number (0x.. ok) or
'|0x..' (OR into the word), '^0x..' (XOR). Container layout:
include/voxcast/scene_file.hpp, src/io/container.cpp.
"""
import struct
import sys

M64 = (1 << 64) - 1
P1, P2, P3, P4, P5 = (0x9E3779B185EBCA87, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9,
                      0x85EBCA77C2B2AE63, 0x27D4EB2F165667C5)


def _rotl(x, r):
    return ((x << r) | (x >> (64 - r))) & M64


def _round(acc, lane):
    acc = (acc + lane * P2) & M64
    return (_rotl(acc, 31) * P1) & M64


def _merge(acc, v):
    acc ^= _round(0, v)
    return (acc * P1 + P4) & M64


def xxh64(data, seed=0):
    """XXH64 as specified by the xxHash project (written from the spec)."""
    n, i = len(data), 0
    if n >= 32:
        v = [(seed + P1 + P2) & M64, (seed + P2) & M64, seed, (seed - P1) & M64]
        while i + 32 <= n:
            for k in range(4):
                v[k] = _round(v[k], struct.unpack_from('<Q', data, i + 8 * k)[0])
            i += 32
        h = (_rotl(v[0], 1) + _rotl(v[1], 7) + _rotl(v[2], 12) + _rotl(v[3], 18)) & M64
        for k in range(4):
            h = _merge(h, v[k])
    else:
        h = (seed + P5) & M64
    h = (h + n) & M64
    while i + 8 <= n:
        h ^= _round(0, struct.unpack_from('<Q', data, i)[0])
        h = (_rotl(h, 27) * P1 + P4) & M64
        i += 8
    if i + 4 <= n:
        h ^= (struct.unpack_from('<I', data, i)[0] * P1) & M64
        h = (_rotl(h, 23) * P2 + P3) & M64
        i += 4
    while i < n:
        h ^= (data[i] * P5) & M64
        h = (_rotl(h, 11) * P1) & M64
        i += 1
    h ^= h >> 33
    h = (h * P2) & M64
    h ^= h >> 29
    h = (h * P3) & M64
    return h ^ (h >> 32)


def sections(buf):
    """(entry offset, name, offset, size, chunk bytes, first hash offset) per
    section, for both container versions (layout: include/voxcast/container.hpp)."""
    version, count = struct.unpack_from('<II', buf, 8)
    if version == 1:
        for e in range(count):
            at = 16 + 32 * e
            fourcc, _, offset, size, _ = struct.unpack_from('<4sIQQQ', buf, at)
            yield at, fourcc.decode('latin-1'), offset, size, max(size, 1), at + 24
        return
    directory = struct.unpack_from('<Q', buf, 16)[0]
    hash_at = directory + 32 * count
    for e in range(count):
        at = directory + 32 * e
        fourcc, chunks, offset, size, chunk_bytes = struct.unpack_from('<4sIQQQ', buf, at)
        yield at, fourcc.decode('latin-1'), offset, size, chunk_bytes, hash_at
        hash_at += 8 * chunks


def rehash(buf, offset, size, chunk_bytes, hash_at):
    """Recomputes a section's chunk hashes and, for version 2, the directory hash."""
    chunk = 0
    while True:
        start = offset + chunk * chunk_bytes
        end = min(start + chunk_bytes, offset + size)
        struct.pack_into('<Q', buf, hash_at + 8 * chunk, xxh64(bytes(buf[start:end])))
        chunk += 1
        if offset + chunk * chunk_bytes >= offset + size:
            break
    if struct.unpack_from('<I', buf, 8)[0] >= 2:
        directory = struct.unpack_from('<Q', buf, 16)[0]
        struct.pack_into('<Q', buf, 32, xxh64(bytes(buf[0:32]) + bytes(buf[directory:])))


def main(argv):
    if len(argv) >= 3 and argv[2] == '--list':
        buf = open(argv[1], 'rb').read()
        for _, name, offset, size, _, _ in sections(buf):
            print(f'{name} offset {offset} size {size} ({size // 4} words)')
        return 0
    if len(argv) < 5:
        print(__doc__, file=sys.stderr)
        return 2
    buf = bytearray(open(argv[1], 'rb').read())
    for _, name, offset, size, chunk_bytes, hash_at in list(sections(buf)):
        if name != argv[3]:
            continue
        for edit in argv[4:]:
            word, value = edit.split('=')
            pos = offset + 4 * int(word, 0)
            if pos + 4 > offset + size:
                raise SystemExit(f'word {word} is past the end of section {name}')
            old = struct.unpack_from('<I', buf, pos)[0]
            if value.startswith('|'):
                new = old | int(value[1:], 0)
            elif value.startswith('^'):
                new = old ^ int(value[1:], 0)
            else:
                new = int(value, 0)
            struct.pack_into('<I', buf, pos, new & 0xFFFFFFFF)
        rehash(buf, offset, size, chunk_bytes, hash_at)
        open(argv[2], 'wb').write(buf)
        return 0
    raise SystemExit(f'no section {argv[3]}')


if __name__ == '__main__':
    sys.exit(main(sys.argv))
