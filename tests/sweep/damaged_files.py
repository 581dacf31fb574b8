#!/usr/bin/env python3
"""Issue 15's damaged-file sweep through the real CLI, every subcommand that
reads a file, every stored scene format and every interop input format.

    tests/sweep/damaged_files.py VOXCAST [--per-file N] [--seed S] [--timeout T]
                                 [--work DIR]
                                 [--only scenes,slices,voxels,volumes,envmaps,meshes]

Samples (built with VOXCAST from tests/data, small): the seven scene formats
(ESVO raw, compressed, contours, contours + compressed, variable depth, DAG
raw, DAG compressed) and a brickmap world, an ESVO slice file (.vxs), the
voxel inputs .vox, .binvox and .vdb (written by `convert`, plus a
MagicaVoxel-written .vox from tests/data/vox), the volumes INRIMAGE
(tests/data/volumes) and MetaImage (.mha, written here), environment maps
(.hdr and .exr, written by `generate sky`) and the mesh formats OBJ, OFF,
PLY, STL, glTF (tests/data/meshes and the seeds of fuzz/corpus/mesh).

Damage, N per sample: scene files get 32-bit payload words set (0xFFFFFFFF,
0, 0x80000000, random, +-1, one bit flipped) with the section hash
recomputed (fuzz/damage_scene.py), so the edit reaches the validators, plus
plain truncations and byte flips; every other file gets truncations, byte
flips, random 32-bit words and inserted/deleted byte runs.

Each damaged file goes through every subcommand that reads it:
  scenes: info, info --json, render (auto camera, beam, hard shadows, AO,
          post-filter; also --depth/--normals and an .exr with layers)
  slice files: info, render (--frames 1, streaming within --budget)
  voxel files: convert to .vox/.binvox/.vdb/.raw, build (ESVO and DAG), and
          render of what build accepted
  volumes: volume render
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
}
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
        old = struct.unpack_from('<I', buf, pos)[0]
        edit = rng.choice(EDITS)
        new = {'random': rng.getrandbits(32), '+1': old + 1, '-1': old - 1,
               'bit': old ^ (1 << rng.randrange(32))}.get(edit, edit)
        struct.pack_into('<I', buf, pos, new & 0xFFFFFFFF)
        damage_scene.rehash(buf, offset, size, chunk_bytes, hash_at)
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
    ap.add_argument('--only', default='scenes,slices,voxels,volumes,envmaps,meshes',
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

    def state():
        return (sw.runs, sw.accepted, sw.refused, len(sw.failures))

    only = set(a.only.split(','))
    # ---- scenes ----
    for name, opts in (SCENE_FORMATS.items() if 'scenes' in only else []):
        src = sw.out(name + '.vxc')
        if not sw.run(['build', spot, '-o', src] + opts.split(), 'sample ' + name):
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
        tally('scene ' + name, before)

    # ---- slice files ----
    if 'slices' in only:
        src = sw.out('sample.vxs')
        if not sw.run(['build', spot, '-o', src, '--resolution', '32', '--slices',
                       '--slice-size', '8K'], 'sample vxs'):
            raise SystemExit('cannot build the .vxs sample')
        before = state()
        for i, f in damaged_files(sw, src, rng, a.per_file):
            label = f'vxs #{i}'
            sw.run(['info', f], label)
            sw.run(['render', f, '-o', sw.out('s.png'), '--size', '16x12', '--frames', '1',
                    '--budget', '1M'], label)
        tally('slices vxs', before)

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
    inr = os.path.join(DATA, 'volumes')
    for v in sorted(os.listdir(inr)) if 'volumes' in only else []:
        if not v.endswith('.inr'):
            continue
        before = state()
        for i, f in damaged_files(sw, os.path.join(inr, v), rng, a.per_file):
            sw.run(['volume', 'render', f, '-o', sw.out('vol.png'), '--size', '24x18'],
                   f'{v} #{i}')
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
            sw.run(['volume', 'render', f, '-o', sw.out('vol.png'), '--size', '24x18'],
                   f'mha #{i}')
        tally('volume sample.mha', before)

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
