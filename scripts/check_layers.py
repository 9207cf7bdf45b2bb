#!/usr/bin/env python3
"""Checks the library's layering from a build's object files (docs/design.md sec. 6.1, "Layout").

For each source file under src/ it lists the other folders' internal headers it includes and the
functions it calls in other folders (undefined symbols of its object resolved to the object that
defines them, by nm), then reports the folder dependency graph, the calls that go up the layers
of LAYERS (or into a folder missing from it), its cycles, pairs of files that call each other,
source files over 900 lines, the folders implementing each public header, and the backend seam
(docs/design.md sec. 6.4): the kernels (src/shade) free of threads, the frame (src/render outside
its backends' folders) calling no kernel and reaching a backend only through its table.

    python3 scripts/check_layers.py [build-dir] [-v]

Exits 1 when a folder calls or includes a folder that is not before it in LAYERS (or is not in
LAYERS), the folder graph has a cycle, two files call each other, a source file (research/ and
cli/ included) is over 900 lines, a public header is implemented by more than one folder or the
backend seam is crossed, else 0. tests/cli_layers.sh runs it in the test suite.
"""
import collections
import os
import re
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
args = [a for a in sys.argv[1:] if not a.startswith('-')]
VERBOSE = '-v' in sys.argv
BUILD = args[0] if args else os.path.join(ROOT, 'build')
OBJDIR = os.path.join(BUILD, 'CMakeFiles', 'penumbra_obj.dir', 'src')


# The folders of src/ from the bottom up (docs/design.md sec. 6.1): a folder may call only the
# folders of the tiers before its own. A new folder is placed here.
LAYERS = [
    ['core'],                # context, errors, allocation, shared internals
    ['scene'],               # the model: scene, mesh, spheres, image, camera, pose, validation
    ['sh'],                  # spherical harmonics
    ['lighting'],            # environment maps: SH projection, lookups, the lights found in them
    ['io'],                  # file formats read into and written from the model
    ['geometry'],            # sphere fit, overlap weights, Embree setup, self transfer
    ['raster'],              # rasterizer
    ['shade'],               # the shading kernels: SH visibility and shading, disk lights
    ['render'],              # the frame, its backends (render/cpu), losses, flat API
    ['reference', 'optim'],  # the ray-traced truth; inverse problems
]
TIER = {f: i for i, tier in enumerate(LAYERS) for f in tier}


def folder(src):
    return src.split('/')[0]


# The backend seam (docs/design.md sec. 6.4). The kernels' folder; the renderer's backends (each
# a folder under render/ whose table the frame gets from its one entry point); and the frame.
KERNELS = 'shade'
BACKENDS = {'render/cpu': 'pen__backend_cpu'}


def backend_of(src):
    return next((b for b in BACKENDS if src.startswith(b + '/')), None)


def source_files(top):
    """Every C source, header and included text under src/<top>, relative to src/."""
    out = []
    for dirpath, _, files in os.walk(os.path.join(ROOT, 'src', top)):
        out += [os.path.relpath(os.path.join(dirpath, f), os.path.join(ROOT, 'src'))
                for f in files if f.endswith(('.c', '.h', '.inc', '.cpp'))]
    return sorted(out)


def kernel_objects():
    """The objects compiled from src/<KERNELS> in every target (the fast kernel is built once
    per instruction set in targets of its own), as (object, source relative to src/); objects of
    sources that have since moved are left out."""
    top, out = os.path.join(BUILD, 'CMakeFiles'), []
    for d in sorted(os.listdir(top)):
        base = os.path.join(top, d, 'src')
        if not d.startswith('penumbra'):
            continue
        for dirpath, _, files in os.walk(os.path.join(base, KERNELS)):
            for f in files:
                src = os.path.relpath(os.path.join(dirpath, f), base)[:-2]
                if f.endswith('.o') and os.path.exists(os.path.join(ROOT, 'src', src)):
                    out.append((os.path.join(dirpath, f), src))
    return sorted(out)


def resolve_include(s, name):
    """A quoted include of src/<s> as a path relative to src/: the including file's folder first
    (as the compiler looks), then src/."""
    here = os.path.normpath(os.path.join(os.path.dirname(s), name))
    if os.path.exists(os.path.join(ROOT, 'src', here)):
        return here
    return os.path.normpath(name)


def seam(sources, calls):
    """The seam's violations, from the text of every file under src/shade and src/render and
    from the objects: a kernel that threads (OpenMP in its text or its objects); a frame file
    (src/render outside a backend's folder) that calls a kernel, includes a kernel's or a
    backend's header itself, or calls into a backend past its table; a backend that calls the
    frame's passes."""
    bad = []
    omp = re.compile(r'#\s*(include\s*<omp\.h>|pragma\s+omp)|_Pragma\s*\(\s*"\s*omp')
    for s in source_files(KERNELS):
        if omp.search(open(os.path.join(ROOT, 'src', s), errors='replace').read()):
            bad.append('%s: threads (omp) in a kernel' % s)
    for o, _ in kernel_objects():
        out = subprocess.run(['nm', '-u', o], capture_output=True, text=True).stdout
        syms = sorted({w for w in out.split() if w.startswith(('omp_', 'GOMP_'))})
        if syms:
            bad.append('%s: threads in a kernel object: %s' % (os.path.basename(o), ' '.join(syms)))
    for s in source_files('render'):
        b = backend_of(s)
        text = open(os.path.join(ROOT, 'src', s), errors='replace').read()
        if b is None:
            for m in re.finditer(r'#\s*include\s*"([^"]+)"', text):
                inc = resolve_include(s, m.group(1))
                if not (inc.startswith(KERNELS + '/') or backend_of(inc)):
                    continue
                if s == 'render/render_internal.h' and inc.startswith(KERNELS + '/'):
                    continue  # the state holds the kernels' parameter types
                bad.append('%s includes %s' % (s, inc))
        for t, syms in sorted(calls.get(s, {}).items()):
            if b is None and folder(t) == KERNELS:
                bad.append('%s calls kernels: %s' % (s, ' '.join(sorted(syms))))
            tb = backend_of(t)
            if b is None and tb is not None and syms - {BACKENDS[tb]}:
                bad.append('%s calls backend %s past its table: %s'
                           % (s, tb, ' '.join(sorted(syms - {BACKENDS[tb]}))))
            if b is not None and t in ('render/forward.c', 'render/backward.c'):
                bad.append('%s calls the frame\'s pass %s' % (s, t))
    return bad


def cycles(graph):
    """Every back edge's cycle found by a depth-first search (enough to say whether any exists)."""
    state, found = {}, []

    def visit(u, stack):
        state[u] = 1
        stack.append(u)
        for v in sorted(graph.get(u, ())):
            if v == u:
                continue
            if state.get(v) == 1:
                found.append(stack[stack.index(v):] + [v])
            elif not state.get(v):
                visit(v, stack)
        stack.pop()
        state[u] = 2

    for u in sorted(graph):
        if not state.get(u):
            visit(u, [])
    return found


def main():
    if not os.path.isdir(OBJDIR):
        sys.exit('no objects in %s: build first' % OBJDIR)
    defined, undefined = {}, collections.defaultdict(set)
    for dirpath, _, files in os.walk(OBJDIR):
        for f in files:
            if not f.endswith('.o'):
                continue
            path = os.path.join(dirpath, f)
            src = os.path.relpath(path, OBJDIR)[:-2]
            if not os.path.exists(os.path.join(ROOT, 'src', src)):
                continue  # the object of a source that has since moved
            out = subprocess.run(['nm', path], capture_output=True, text=True, check=True).stdout
            for line in out.splitlines():
                p = line.split()
                if len(p) == 3 and p[1] in 'TDBRW':
                    defined.setdefault(p[2], src)
                elif len(p) == 2 and p[0] == 'U':
                    undefined[src].add(p[1])
    for path, src in kernel_objects():  # the per-instruction-set builds' symbols too
        out = subprocess.run(['nm', path], capture_output=True, text=True, check=True).stdout
        for line in out.splitlines():
            p = line.split()
            if len(p) == 3 and p[1] in 'TDBRW':
                defined.setdefault(p[2], src)
    sources = sorted(set(undefined) | set(defined.values()))
    calls = collections.defaultdict(lambda: collections.defaultdict(set))
    for s in sources:
        for sym in undefined[s]:
            if sym in defined and defined[sym] != s:
                calls[s][defined[sym]].add(sym)
    graph = collections.defaultdict(set)
    for s in sources:
        text = open(os.path.join(ROOT, 'src', s), errors='replace').read()
        heads = sorted({m.group(1) for m in re.finditer(r'#include "([a-z_]+/[a-z_]+\.(?:h|inc))"', text)
                        if not m.group(1).startswith('penumbra/') and folder(m.group(1)) != folder(s)})
        by_folder = collections.defaultdict(set)
        for t, syms in calls[s].items():
            if folder(t) != folder(s):
                by_folder[folder(t)] |= syms
        graph[folder(s)] |= set(by_folder) | {folder(h) for h in heads}
        if VERBOSE and (heads or by_folder):
            print(s)
            for h in heads:
                print('    includes', h)
            for f, syms in sorted(by_folder.items()):
                print('    calls %s: %s' % (f, ' '.join(sorted(syms))))
    print('folder graph:')
    for f in sorted(graph):
        print('    %-10s -> %s' % (f, ', '.join(sorted(graph[f] - {f})) or '(nothing)'))
    upward = sorted('%s -> %s' % (f, g) for f in graph for g in graph[f] - {f}
                    if f not in TIER or g not in TIER or TIER[g] >= TIER[f])
    print('calls up the layers (or into a folder not in LAYERS):', ', '.join(upward) or 'none')
    folder_cycles = cycles(graph)
    print('folder cycles:', folder_cycles or 'none')
    pairs = sorted({tuple(sorted((s, t))) for s in sources for t in calls[s] if s in calls[t]})
    print('files calling each other:', pairs or 'none')
    big = []
    for dirpath, _, files in (w for top in ('src', 'research', 'cli')
                              for w in os.walk(os.path.join(ROOT, top))):
        for f in files:
            path = os.path.join(dirpath, f)
            n = sum(1 for _ in open(path, errors='replace'))
            if n > 900:
                big.append('%s (%d)' % (os.path.relpath(path, ROOT), n))
    print('source files over 900 lines:', ', '.join(sorted(big)) or 'none')
    print('public headers -> folders implementing their functions:')
    hdir = os.path.join(ROOT, 'include', 'penumbra')
    split = []
    for h in sorted(os.listdir(hdir)):
        text = re.sub(r'/\*.*?\*/', '', open(os.path.join(hdir, h)).read(), flags=re.S)
        impl = collections.Counter(folder(defined[n]) for n in set(re.findall(r'\b(pen_[a-z0-9_]+)\s*\(', text))
                                   if n in defined)
        print('    %-12s %s' % (h, ', '.join('%s (%d)' % kv for kv in sorted(impl.items())) or '(includes only)'))
        if len(impl) > 1:
            split.append(h)
    print('public headers implemented in more than one folder:', ', '.join(split) or 'none')
    crossed = seam(sources, calls)
    print('backend seam crossed:', '; '.join(crossed) or 'none')
    return 1 if upward or folder_cycles or pairs or big or split or crossed else 0


if __name__ == '__main__':
    sys.exit(main())
