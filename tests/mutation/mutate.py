#!/usr/bin/env python3
"""Mutation check driver (see run.sh for usage; the list is mutations.txt).

mutations.txt holds one entry per mutation:

    [name]
    file: path/relative/to/the/repository
    build: target [target...]        # test executables to rebuild
    test: ctest -R regex             # the tests expected to catch it
    why: one line shown in the report
    - literal text that must occur exactly once in the file
    + its replacement
    (more -/+ pairs: all applied to the same file)

Lines starting with '#' and blank lines are ignored. Text after '- ' / '+ '
is taken literally (no regex), to the end of the line.
"""
import argparse
import fcntl
import os
import re
import subprocess
import sys
import time


class ListError(Exception):
    pass


def parse(path):
    muts, cur = [], None
    for no, raw in enumerate(open(path, encoding="utf-8"), 1):
        line = raw.rstrip("\n")
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        m = re.fullmatch(r"\[([A-Za-z0-9_.-]+)\]", line.strip())
        if m:
            cur = {"name": m.group(1), "edits": [], "line": no}
            muts.append(cur)
            continue
        if cur is None:
            raise ListError(f"{path}:{no}: text before the first [name]")
        if line.startswith("- "):
            cur["edits"].append([line[2:], None])
        elif line.startswith("+ "):
            if not cur["edits"] or cur["edits"][-1][1] is not None:
                raise ListError(f"{path}:{no}: '+' without a preceding '-'")
            cur["edits"][-1][1] = line[2:]
        else:
            key, sep, val = line.partition(":")
            if not sep or key.strip() not in ("file", "build", "test", "why"):
                raise ListError(f"{path}:{no}: cannot read {line!r}")
            cur[key.strip()] = val.strip()
    names = set()
    for m in muts:
        for key in ("file", "build", "test"):
            if key not in m:
                raise ListError(f"{path}:{m['line']}: [{m['name']}] has no '{key}:'")
        if not m["edits"] or any(r is None for _, r in m["edits"]):
            raise ListError(f"{path}:{m['line']}: [{m['name']}] needs '-'/'+' pairs")
        if m["name"] in names:
            raise ListError(f"{path}:{m['line']}: duplicate name {m['name']}")
        names.add(m["name"])
    return muts


def apply_edits(text, m):
    """The mutated text; raises ListError unless every pattern occurs exactly once."""
    for pat, rep in m["edits"]:
        n = text.count(pat)
        if n != 1:
            raise ListError(
                f"[{m['name']}] pattern occurs {n} times in {m['file']} (must be exactly once):\n"
                f"    {pat}")
        text = text.replace(pat, rep)
    return text


def tree_files(root):
    out = subprocess.run(["git", "-C", root, "ls-files", "-co", "--exclude-standard", "-z"],
                         check=True, capture_output=True).stdout.decode()
    return [f for f in out.split("\0") if f]


def write_if_changed(dst, data):
    """Writes only changed files, so the scratch build stays incremental."""
    try:
        with open(dst, "rb") as f:
            if f.read() == data:
                return False
    except FileNotFoundError:
        os.makedirs(os.path.dirname(dst), exist_ok=True)
    with open(dst, "wb") as f:
        f.write(data)
    return True


def sync(root, scratch):
    """Mirrors the tree's files into scratch; files it no longer has are removed
    (the manifest lists what the previous sync copied)."""
    files = [f for f in tree_files(root)
             if os.path.isfile(os.path.join(root, f)) and not os.path.islink(os.path.join(root, f))]
    manifest = os.path.join(scratch, ".mutation-manifest")
    if os.path.exists(manifest):
        for rel in set(open(manifest, encoding="utf-8").read().splitlines()) - set(files):
            if os.path.isfile(os.path.join(scratch, rel)):
                os.remove(os.path.join(scratch, rel))
    changed = 0
    for rel in files:
        with open(os.path.join(root, rel), "rb") as f:
            changed += write_if_changed(os.path.join(scratch, rel), f.read())
    with open(manifest, "w", encoding="utf-8") as f:
        f.write("\n".join(files) + "\n")
    return changed


def run(cmd, log, timeout=None):
    """Runs cmd with its output appended to the log; returns (exit code, output)."""
    with open(log, "ab") as out:
        out.write(("\n$ " + " ".join(cmd) + "\n").encode())
        try:
            p = subprocess.run(cmd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                               timeout=timeout)
            out.write(p.stdout)
            return p.returncode, p.stdout.decode(errors="replace")
        except subprocess.TimeoutExpired as e:
            out.write((e.stdout or b"") + b"\n(timed out)\n")
            return 124, ""


def failed_tests(ctest_output):
    """Names listed under ctest's 'The following tests FAILED:' (a value-
    parameterized test's line carries '  # GetParam() = ...' before its
    status), with the instances of one parameterized test folded into
    'Suite/Test.Name/* (n)' to keep the report readable."""
    _, _, tail = ctest_output.partition("The following tests FAILED:")
    names = re.findall(r"^\s*\d+ - (\S+)(?:\s+#[^\n]*?)? \(", tail, re.M)
    groups = {}
    for n in names:
        head, sep, _ = n.rpartition("/")
        key = head + "/*" if sep and "." in head else n
        groups[key] = groups.get(key, 0) + 1
    return [f"{k} ({c})" if k.endswith("/*") else k for k, c in groups.items()]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--root", required=True)
    ap.add_argument("--list", required=True)
    ap.add_argument("--scratch", required=True)
    ap.add_argument("--jobs", default="2")
    ap.add_argument("--check", action="store_true", help="only verify the patterns")
    ap.add_argument("--timeout", type=int, default=900, help="per ctest run, seconds")
    ap.add_argument("--test", help="run this ctest -R subset for every mutation instead")
    ap.add_argument("--build", help="rebuild these targets (space-separated) instead")
    ap.add_argument("names", nargs="*")
    a = ap.parse_args()

    try:
        muts = parse(a.list)
        unknown = [n for n in a.names if n not in {m["name"] for m in muts}]
        if unknown:
            raise ListError("unknown mutation(s): " + " ".join(unknown))
        if a.names:
            muts = [m for m in muts if m["name"] in a.names]
        for m in muts:  # overrides: how would another subset fare?
            m["test"] = a.test or m["test"]
            m["build"] = a.build or m["build"]
        originals = {}
        for m in muts:
            path = os.path.join(a.root, m["file"])
            if not os.path.isfile(path):
                raise ListError(f"[{m['name']}] no file {m['file']}")
            originals.setdefault(m["file"], open(path, encoding="utf-8").read())
            apply_edits(originals[m["file"]], m)
    except ListError as e:
        print(f"mutation: ERROR: {e}", file=sys.stderr)
        return 2
    print(f"mutation: {len(muts)} mutation(s), every pattern matches exactly once")
    if a.check:
        return 0

    os.makedirs(a.scratch, exist_ok=True)
    lock = open(os.path.join(a.scratch, ".mutation-lock"), "w")
    try:
        fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        print(f"mutation: waiting for another run in {a.scratch}", flush=True)
        fcntl.flock(lock, fcntl.LOCK_EX)
    # The copy mirrors the tree (sources at the root, build/ inside) so that
    # compile commands, relative to a ccache base directory above both, are
    # the same as a developer build's and hit its cache.
    src, build = a.scratch, os.path.join(a.scratch, "build")
    log = os.path.join(a.scratch, "mutation.log")
    open(log, "w").close()
    base = os.environ.get("CCACHE_BASEDIR", "")
    if not base or os.path.commonpath([os.path.abspath(base), src]) != os.path.abspath(base):
        os.environ["CCACHE_BASEDIR"] = os.path.commonpath([src, a.root])
    t0 = time.time()
    print(f"mutation: scratch copy {src} ({sync(a.root, src)} file(s) updated), log {log}")
    if run(["cmake", "-S", src, "-B", build, "-G", "Ninja", "-DCMAKE_BUILD_TYPE=Release",
            "-DVOXCAST_BUILD_BENCH=OFF"], log)[0] != 0:
        print("mutation: ERROR: cmake configure failed (see the log)", file=sys.stderr)
        return 2

    def build_targets(targets):
        cmd = ["cmake", "--build", build, "-j", a.jobs]
        for t in targets:
            cmd += ["--target", t]
        return run(cmd, log)[0]

    def ctest(regex):
        return run(["ctest", "--test-dir", build, "-R", regex, "-j", a.jobs, "--output-on-failure",
                    "--no-tests=error", "--timeout", str(a.timeout)], log, timeout=a.timeout * 4)

    def count_tests(regex):
        out = subprocess.run(["ctest", "--test-dir", build, "-N", "-R", regex],
                             capture_output=True, text=True).stdout
        m = re.search(r"Total Tests:\s*(\d+)", out)
        return int(m.group(1)) if m else 0

    # Baseline: the unmutated tree must pass every subset, and every regex
    # must select some test (an empty selection would pass and hide a miss).
    targets = sorted({t for m in muts for t in m["build"].split()})
    print(f"mutation: baseline build of {' '.join(targets)}", flush=True)
    if build_targets(targets) != 0:
        print("mutation: ERROR: the unmutated tree does not build (see the log)", file=sys.stderr)
        return 2
    for m in muts:
        if count_tests(m["test"]) == 0:
            print(f"mutation: ERROR: [{m['name']}] test regex {m['test']!r} selects no test",
                  file=sys.stderr)
            return 2
    tb = time.time()
    # One run per distinct regex (CMake's regex engine has no anchors inside
    # alternatives, so the subsets cannot be joined into one expression).
    for regex in dict.fromkeys(m["test"] for m in muts):
        if ctest(regex)[0] != 0:
            print(f"mutation: ERROR: the unmutated tree fails {regex!r} (see the log)",
                  file=sys.stderr)
            return 2
    print(f"mutation: baseline passes ({time.time() - tb:.0f} s)", flush=True)

    results = []
    for m in muts:
        path = os.path.join(src, m["file"])
        original = open(path, encoding="utf-8").read()
        ts = time.time()
        with open(log, "a") as f:
            f.write(f"\n==== mutation {m['name']} ====\n")
        try:
            with open(path, "w", encoding="utf-8") as f:
                f.write(apply_edits(original, m))
            failed = []
            if build_targets(m["build"].split()) != 0:
                status = "ERROR (does not compile)"
            else:
                rc, out = ctest(m["test"])
                failed = failed_tests(out)
                status = "CAUGHT" if rc != 0 else "MISSED"
        finally:
            with open(path, "w", encoding="utf-8") as f:  # new mtime: rebuilt next time
                f.write(original)
        dt = time.time() - ts
        results.append((m, status, dt, failed))
        print(f"mutation: {status:7s} {m['name']} ({dt:.0f} s)", flush=True)

    build_targets(targets)  # leave the scratch build unmutated
    print(f"\n{'mutation':34s} {'result':8s} {'time':>6s}  failing tests (of {'-R'} subset)")
    for m, status, dt, failed in results:
        print(f"{m['name']:34s} {status:8s} {dt:5.0f}s  {' '.join(failed) or '-'}  ({m['test']})")
    caught = sum(s == "CAUGHT" for _, s, _, _ in results)
    print(f"\nmutation: {caught}/{len(results)} caught, total {time.time() - t0:.0f} s")
    if any(s.startswith("ERROR") for _, s, _, _ in results):
        return 2
    return 0 if caught == len(results) else 1


if __name__ == "__main__":
    sys.exit(main())
