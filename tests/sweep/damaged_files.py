#!/usr/bin/env python3
"""Issue 15's damaged-file sweep through the real CLI, every subcommand that
reads a file, every stored scene format and every interop input format.

    tests/sweep/damaged_files.py VOXCAST [--per-file N] [--seed S] [--timeout T]
                                 [--work DIR]
                                 [--only scenes,journals,slices,voxels,volumes,envmaps,meshes]

Samples (built with VOXCAST from tests/data, small): the seven scene formats
(ESVO raw, compressed, contours, contours + compressed, variable depth, DAG
raw, DAG compressed), a brickmap world built from a mesh and one written by
`generate terrain`, the edit journal of a world edited in place, ESVO
slice files (.vxs, raw and compressed attributes), the
voxel inputs .vox, .binvox and .vdb (written by `convert`, plus a
MagicaVoxel-written .vox from tests/data/vox), the volumes INRIMAGE
(tests/data/volumes), MetaImage (.mha, written here) and an OpenVDB
FloatGrid (.vdb, written by `volume export`), environment maps
(.hdr and .exr, written by `generate sky`) and the mesh formats OBJ, OFF,
PLY, STL, glTF (tests/data/meshes and the seeds of fuzz/corpus/mesh).

Damage, N per sample: scene files get 32-bit payload words set (0xFFFFFFFF,
0, 0x80000000, random, +-1, one bit flipped) with the section hash
recomputed (fuzz/damage_scene.py), so the edit reaches the validators, plus
plain truncations and byte flips; edit journals get the same word edits
inside one record (head or payload) with the record's two hashes
recomputed, plus truncations and byte flips; every other file gets truncations, byte
flips, random 32-bit words and inserted/deleted byte runs.

Each damaged file goes through every subcommand that reads it:
  scenes: info, info --json, render (auto camera, beam, hard shadows, AO,
          post-filter; also --depth/--normals and an .exr with layers);
          brickmap worlds also render --stream (with and without --dxt1)
          and edit -o
  journals (beside their intact world): info, render, render --stream,
          edit -o
  slice files: info, render (--frames 1, streaming within --budget)
  voxel files: convert to .vox/.binvox/.vdb/.raw, build (ESVO and DAG), and
          render of what build accepted
  volumes: volume render, volume info
  environment maps: render --gi 1 --env of a small scene
  meshes: build (ESVO, DAG), convert to .vox, bench (tiny)
It must exit 0 (then stderr holds only warnings), or exit 1 or 2 with exactly
one stderr line "voxcast: error: ..."; a signal, a timeout, another status or
more lines is a failure. Prints the failures and a summary per format; exit
status 1 if anything failed. (view needs a display; its loader is the same
load_scene that info and render use.)
"""
import argparse
import os
import random
import shutil
import struct
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(os.path.dirname(HERE))
sys.path.insert(0, os.path.join(ROOT, 'fuzz'))
import damage_scene  # noqa: E402  (sections, rehash)

DATA = os.path.join(ROOT, 'tests', 'data')
SCENE_FORMATS = {
    'esvo_raw': '--resolution 32',
    'esvo_compressed': '--resolution 32 --attributes compressed',
    'esvo_contours': '--resolution 32 --contours',
    'esvo_contours_compressed': '--resolution 32 --contours --attributes compressed',
    'esvo_variable_depth': '--resolution 64 --contours --geometry-error 1',
    'dag_raw': '--resolution 64 --format dag',
    'dag_compressed': '--resolution 64 --format dag --attributes compressed',
    'brickmap': '--resolution 64 --format brickmap',
    # not built from the mesh: `generate terrain` (a brickgrid cut off in y)
    'brickmap_terrain': None,
}
BRICKMAPS = ('brickmap', 'brickmap_terrain')
EDITS = (0xFFFFFFFF, 0, 0x80000000, 'random', '+1', '-1', 'bit')


class Sweep:
    def __init__(self, voxcast, work, timeout):
        self.voxcast, self.work, self.timeout = voxcast, work, timeout
        self.runs = self.accepted = self.refused = 0
        self.failures = []

    def run(self, args, label):
        """One CLI run; records whether it obeyed the convention."""
        self.runs += 1
        try:
            p = subprocess.run([self.voxcast] + args, stdout=subprocess.DEVNULL,
                               stderr=subprocess.PIPE, timeout=self.timeout)
        except subprocess.TimeoutExpired:
            self.failures.append(f'TIMEOUT {label}: {" ".join(args)}')
            return False
        err = p.stderr.decode('utf-8', 'replace').splitlines()
        if p.returncode == 0:
            stray = [ln for ln in err if not ln.startswith('voxcast: warning: ')
                     and not ln.startswith('mesh: ')]
            if stray:
                self.failures.append(f'STRAY {label}: {" ".join(args)}: {stray[:2]}')
                return False
            self.accepted += 1
            return True
        if p.returncode in (1, 2) and len(err) == 1 and err[0].startswith('voxcast: error: '):
            self.refused += 1
            return False
        what = f'signal {-p.returncode}' if p.returncode < 0 else f'exit {p.returncode}'
        self.failures.append(f'FAIL ({what}, {len(err)} lines) {label}: {" ".join(args)}: '
                             f'{err[:3]}')
        return False

    def out(self, name):
        return os.path.join(self.work, name)


def edit_word(buf, pos, rng):
    """One of EDITS applied to the little-endian 32-bit word at buf[pos]."""
    old = struct.unpack_from('<I', buf, pos)[0]
    edit = rng.choice(EDITS)
    new = {'random': rng.getrandbits(32), '+1': old + 1, '-1': old - 1,
           'bit': old ^ (1 << rng.randrange(32))}.get(edit, edit)
    struct.pack_into('<I', buf, pos, new & 0xFFFFFFFF)


def scene_damage(data, rng, n):
    """n damaged copies of a scene: payload word edits with the hash fixed up
    (most of them), truncations and byte flips."""
    secs = list(damage_scene.sections(data))
    for k in range(n):
        buf = bytearray(data)
        kind = k % 8
        if kind == 6:  # truncation
            yield bytes(buf[:rng.randrange(len(buf))])
            continue
        if kind == 7:  # plain byte flip (checksums catch it)
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
            yield bytes(buf)
            continue
        _, _, offset, size, chunk_bytes, hash_at = rng.choice(secs)
        if size < 4:
            yield bytes(buf)
            continue
        pos = offset + 4 * rng.randrange(size // 4)
        edit_word(buf, pos, rng)
        damage_scene.rehash(buf, offset, size, chunk_bytes, hash_at)
        yield bytes(buf)


def journal_records(data):
    """(head offset, payload size) of every whole record of an edit journal
    (include/voxcast/brickmap_file.hpp: a 32-byte file head, then records of a
    40-byte head and a payload)."""
    at, out = 32, []
    while at + 40 <= len(data) and data[at:at + 4] == b'JREC':
        size = struct.unpack_from('<Q', data, at + 16)[0]
        if at + 40 + size > len(data):
            break
        out.append((at, size))
        at += 40 + size
    return out


def rehash_record(buf, at):
    """Recomputes a journal record's payload and head hashes (the payload
    size is read from the head as it now stands, clipped to the file)."""
    size = min(struct.unpack_from('<Q', buf, at + 16)[0], max(0, len(buf) - at - 40))
    struct.pack_into('<Q', buf, at + 24, damage_scene.xxh64(bytes(buf[at + 40:at + 40 + size])))
    struct.pack_into('<Q', buf, at + 32, damage_scene.xxh64(bytes(buf[at:at + 32])))


def journal_damage(data, rng, n):
    """n damaged copies of an edit journal: 32-bit word edits inside one
    record, its hashes recomputed so the edit reaches the replay (most of
    them; the head's type, transaction and size words too), truncations and
    byte flips."""
    recs = journal_records(data)
    for k in range(n):
        buf = bytearray(data)
        kind = k % 8
        if kind == 6 or not recs:
            yield bytes(buf[:rng.randrange(len(buf))])
            continue
        if kind == 7:
            buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
            yield bytes(buf)
            continue
        at, size = rng.choice(recs)
        if kind == 5 or size < 4:  # head: type, transaction or payload size
            pos = at + rng.choice((4, 8, 12, 16, 20))
        else:
            pos = at + 40 + 4 * rng.randrange(size // 4)
        edit_word(buf, pos, rng)
        rehash_record(buf, at)
        yield bytes(buf)


def byte_damage(data, rng, n):
    """n damaged copies of a file without checksums."""
    for k in range(n):
        buf = bytearray(data)
        kind = k % 5
        if kind == 0:
            buf = buf[:rng.randrange(len(buf))]
        elif kind == 1:
            for _ in range(rng.randint(1, 4)):
                buf[rng.randrange(len(buf))] ^= 1 << rng.randrange(8)
        elif kind == 2 and len(buf) >= 4:
            at = rng.randrange(len(buf) - 3)
            v = rng.choice((0xFFFFFFFF, 0, 0x80000000, 0x7FFFFFFF, rng.getrandbits(32)))
            struct.pack_into('<I', buf, at, v)
        elif kind == 3:
            at = rng.randrange(len(buf))
            del buf[at:at + rng.randint(1, 64)]
        else:
            at = rng.randrange(len(buf) + 1)
            buf[at:at] = bytes(rng.getrandbits(8) for _ in range(rng.randint(1, 64)))
        yield bytes(buf)


def damaged_files(sw, src, rng, n, damage=byte_damage):
    """Writes each damaged copy of src to one work file (same extension) and
    yields (index, path)."""
    data = open(src, 'rb').read()
    f = sw.out('bad' + os.path.splitext(src)[1])
    for i, bad in enumerate(damage(data, rng, n)):
        open(f, 'wb').write(bad)
        yield i, f


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('voxcast')
    ap.add_argument('--per-file', type=int, default=40)
    ap.add_argument('--seed', type=int, default=2026)
    ap.add_argument('--timeout', type=float, default=60)
    ap.add_argument('--work')
    ap.add_argument('--only', default='scenes,journals,slices,voxels,volumes,envmaps,meshes',
                    help='comma-separated parts of the sweep to run')
    a = ap.parse_args()
    rng = random.Random(a.seed)
    work = a.work or tempfile.mkdtemp(prefix='voxcast-damage-')
    os.makedirs(work, exist_ok=True)
    sw = Sweep(os.path.abspath(a.voxcast), work, a.timeout)
    spot = os.path.join(DATA, 'meshes', 'spot.obj')
    summary = []

    def tally(name, before):
        runs, acc, ref, fails = before
        summary.append(f'{name}: {sw.runs - runs} runs, {sw.accepted - acc} accepted, '
                       f'{sw.refused - ref} refused, {len(sw.failures) - fails} failures')
        # As each part ends, so that a long sweep shows where it is.
        print(summary[-1], *sw.failures[fails:], sep='\n', flush=True)

    def state():
        return (sw.runs, sw.accepted, sw.refused, len(sw.failures))

    only = set(a.only.split(','))
    # ---- scenes ----
    def terrain(out):
        return sw.run(['generate', 'terrain', '--size', '72x40x64', '--seed', '5', '-o', out],
                      'sample terrain')

    def brickmap_runs(f, label):
        """What reads a brickmap world besides info and render."""
        for dxt1 in ([], ['--dxt1']):
            sw.run(['render', f, '--stream', '--frames', '2', '--budget', '1M', '-o',
                    sw.out('st.png'), '--size', '16x12'] + dxt1, label)
        sw.run(['edit', f, '--sphere', '0.5,0.3,0.5,0.1', '--add', '-o', sw.out('e.vxc')], label)

    for name, opts in (SCENE_FORMATS.items() if 'scenes' in only else []):
        src = sw.out(name + '.vxc')
        if not (sw.run(['build', spot, '-o', src] + opts.split(), 'sample ' + name) if opts
                else terrain(src)):
            raise SystemExit(f'cannot build the {name} sample')
        before = state()
        for i, f in damaged_files(sw, src, rng, a.per_file, scene_damage):
            label = f'{name} #{i}'
            sw.run(['info', f], label)
            sw.run(['info', '--json', f], label)
            sw.run(['render', f, '-o', sw.out('r.png'), '--size', '24x18', '--beam', '4',
                    '--shadows', 'hard', '--ao', '2', '--filter', '--depth', sw.out('r.pfm'),
                    '--normals', sw.out('n.png')], label)
            sw.run(['render', f, '-o', sw.out('r.exr'), '--aov', 'depth,normal', '--size',
                    '16x12'], label)
            if name in BRICKMAPS:
                brickmap_runs(f, label)
        tally('scene ' + name, before)

    # ---- edit journals (brickmap worlds edited in place) ----
    for name in (BRICKMAPS if 'journals' in only else []):
        world = sw.out(name + '-j.vxc')
        ok = (sw.run(['build', spot, '-o', world] + SCENE_FORMATS[name].split(), 'sample ' + name)
              if SCENE_FORMATS[name] else terrain(world))
        for brush in (['--sphere', '0.5,0.4,0.5,0.15', '--add'],
                      ['--box', '0.3,0.3,0.3,0.6,0.5,0.6', '--remove'],
                      ['--sphere', '0.4,0.3,0.6,0.2', '--paint', '0.1,0.2,0.9']):
            ok = ok and sw.run(['edit', world] + brush, 'journal sample ' + name)
        ok = ok and sw.run(['edit', world, '--snow', '2'], 'journal sample ' + name)
        journal = world + '.journal'
        if not ok or not os.path.exists(journal):
            raise SystemExit(f'cannot write the {name} journal sample')
        data = open(journal, 'rb').read()
        bad_world = sw.out('jbad.vxc')
        shutil.copyfile(world, bad_world)
        before = state()
        for i, bad in enumerate(journal_damage(data, rng, a.per_file)):
            open(bad_world + '.journal', 'wb').write(bad)
            label = f'{name} journal #{i}'
            sw.run(['info', bad_world], label)
            sw.run(['render', bad_world, '-o', sw.out('r.png'), '--size', '24x18', '--beam', '4',
                    '--shadows', 'hard'], label)
            brickmap_runs(bad_world, label)
        tally(f'journal {name} ({len(journal_records(data))} records)', before)

    # ---- slice files ----
    if 'slices' in only:
        # Raw attributes, and §5.5 blocks per slice (decoded on read).
        for name, extra in (('vxs', []), ('vxs compressed', ['--attributes', 'compressed'])):
            src = sw.out('sample.vxs')
            if not sw.run(['build', spot, '-o', src, '--resolution', '32', '--slices',
                           '--slice-size', '8K'] + extra, f'sample {name}'):
                raise SystemExit(f'cannot build the {name} sample')
            before = state()
            for i, f in damaged_files(sw, src, rng, a.per_file):
                label = f'{name} #{i}'
                sw.run(['info', f], label)
                sw.run(['render', f, '-o', sw.out('s.png'), '--size', '16x12', '--frames', '1',
                        '--budget', '1M'], label)
                sw.run(['render', f, '-o', sw.out('w.png'), '--size', '16x12'], label)
            tally(f'slices {name}', before)

    # ---- voxel files ----
    voxel_samples = []
    for ext in ('vox', 'binvox', 'vdb') if 'voxels' in only else []:
        f = sw.out('sample.' + ext)
        if not sw.run(['convert', spot, f, '--resolution', '32'], 'sample ' + ext):
            raise SystemExit(f'cannot write the .{ext} sample')
        voxel_samples.append((ext, f))
    if 'voxels' in only:
        voxel_samples.append(('vox (MagicaVoxel)', os.path.join(DATA, 'vox', 'chr_knight.vox')))
    for name, src in voxel_samples:
        before = state()
        for i, f in damaged_files(sw, src, rng, a.per_file):
            label = f'{name} #{i}'
            for out in ('c.vox', 'c.binvox', 'c.vdb', 'c.raw'):
                sw.run(['convert', f, sw.out(out)], label)
            for fmt in ('esvo', 'dag'):
                scene = sw.out('v.vxc')
                if os.path.exists(scene):
                    os.remove(scene)
                if sw.run(['build', f, '-o', scene, '--format', fmt], label):
                    sw.run(['render', scene, '-o', sw.out('v.png'), '--size', '16x12'], label)
        tally('voxels ' + name, before)

    # ---- volumes ----
    def volume_runs(f, label):
        sw.run(['volume', 'render', f, '-o', sw.out('vol.png'), '--size', '24x18'], label)
        sw.run(['volume', 'info', f], label)

    inr = os.path.join(DATA, 'volumes')
    for v in sorted(os.listdir(inr)) if 'volumes' in only else []:
        if not v.endswith('.inr'):
            continue
        before = state()
        for i, f in damaged_files(sw, os.path.join(inr, v), rng, a.per_file):
            volume_runs(f, f'{v} #{i}')
        tally('volume ' + v, before)

    # MetaImage: a small sphere of bytes after a local-data header.
    if 'volumes' in only:
        mha = sw.out('sample.mha')
        with open(mha, 'wb') as out:
            out.write(b'ObjectType = Image\nNDims = 3\nDimSize = 8 8 8\n'
                      b'ElementType = MET_UCHAR\nElementDataFile = LOCAL\n')
            out.write(bytes(((x * 7 + y * 3 + z) % 256 if (x - 4) ** 2 + (y - 4) ** 2 +
                             (z - 4) ** 2 < 10 else 0)
                            for z in range(8) for y in range(8) for x in range(8)))
        before = state()
        for i, f in damaged_files(sw, mha, rng, a.per_file):
            volume_runs(f, f'mha #{i}')
        tally('volume sample.mha', before)
        # An OpenVDB FloatGrid written by `volume export`.
        vdb = sw.out('volume.vdb')
        if not sw.run(['volume', 'export', 'procedural:cloud', '-o', vdb, '--resolution', '16'],
                      'sample volume .vdb'):
            raise SystemExit('cannot write the .vdb volume sample')
        before = state()
        for i, f in damaged_files(sw, vdb, rng, a.per_file):
            volume_runs(f, f'volume.vdb #{i}')
        tally('volume volume.vdb', before)

    # ---- environment maps ----
    if 'envmaps' in only:
        scene = sw.out('env-scene.vxc')
        if not sw.run(['build', spot, '-o', scene, '--resolution', '16'], 'env scene'):
            raise SystemExit('cannot build the environment map scene')
        for ext in ('hdr', 'exr'):
            src = sw.out('sky.' + ext)
            if not sw.run(['generate', 'sky', '-o', src, '--sky-size', '32x16'], 'sky ' + ext):
                raise SystemExit(f'cannot write the .{ext} sky')
            before = state()
            for i, f in damaged_files(sw, src, rng, a.per_file):
                sw.run(['render', scene, '-o', sw.out('g.png'), '--size', '16x12', '--gi', '1',
                        '--env', f], f'{ext} #{i}')
            tally('environment .' + ext, before)

    # ---- meshes ----
    meshes = [os.path.join(DATA, 'meshes', 'spot.obj'),
              os.path.join(DATA, 'meshes', 'camel.off')] if 'meshes' in only else []
    # The fuzz corpus' small seeds (first byte = the extension index of
    # fuzz_mesh.cpp): OBJ with mtllib, PLY, STL, OFF, glTF, GLB.
    corpus = os.path.join(ROOT, 'fuzz', 'corpus', 'mesh')
    kext = ['.obj', '.ply', '.stl', '.off', '.gltf', '.glb', '.dae']
    for seed in sorted(os.listdir(corpus)) if meshes else []:
        raw = open(os.path.join(corpus, seed), 'rb').read()
        if raw:
            f = sw.out('seed-' + seed + kext[raw[0] % 7])
            open(f, 'wb').write(raw[1:])
            meshes.append(f)
    for src in meshes:
        before = state()
        for i, f in damaged_files(sw, src, rng, a.per_file):
            label = f'{os.path.basename(src)} #{i}'
            sw.run(['build', f, '-o', sw.out('m.vxc'), '--resolution', '32'], label)
            sw.run(['build', f, '-o', sw.out('m.vxc'), '--resolution', '32', '--format', 'dag'],
                   label)
            sw.run(['convert', f, sw.out('m.vox'), '--resolution', '32'], label)
            if i % 4 == 0:  # bench builds an Embree BVH too: every fourth file
                sw.run(['bench', f, '--resolution', '32', '--size', '16x12', '--repeat', '1'],
                       label)
        tally('mesh ' + os.path.basename(src), before)

    print('summary:')
    for line in summary:
        print(line)
    for line in sw.failures:
        print(line)
    print(f'damaged-file sweep: {sw.runs} runs, {sw.accepted} accepted, {sw.refused} refused in '
          f'one line, {len(sw.failures)} failures')
    if not a.work:
        shutil.rmtree(work, ignore_errors=True)
    return 1 if sw.failures else 0


if __name__ == '__main__':
    sys.exit(main())
