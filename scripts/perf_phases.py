#!/usr/bin/env python3
"""Time shares of the phases of an mpmcg step from a `perf record` profile.

    perf record -F 1999 -o prof.data -- taskset -c 0 target/release/mpmcg run SCENE --threads 1 --quiet
    python3 scripts/perf_phases.py prof.data [--binary target/release/mpmcg]

The release build's line tables carry the inlining chain of every address, so each
sample of mpmcg's own code is resolved (addr2line -i) to the innermost function that is
a phase of a step: `Solver::domain_weights`, `averaged_force`, `grid_velocity`,
`averaged_velocity_gradient`, `relocate`, the tile pass (`wrap_and_flag`, the
locators, `touch_runs`, `run_nodes`), `sort`, `remap`,
`kernel::scatter_slabs`, `SlabOrder::build`, `kernel::gather`, `kernel::update_stress`
(the material's stress, a function of its own, is shown apart), and the run loop's
`totals` (history rows) and rescue copy. Phases that run twice in a step (the grid
updates of MUSL, the scatters of USF or of MUSL with XPIC) are told apart by order: a
scatter after a gather, a remap or a stress update is the second one (a lone sample
does not count; on small scenes, a few samples per step, add the two). Samples outside mpmcg (libm's
`log`, `memset`, `memmove`, the kernel) count with the phase of the mpmcg sample next
to them in time (the previous one), and so does a helper that is not inlined (in 3D,
`Geom::locate`); `memset` is the scatter's clear of the node records (and, labelled "clear grid"
too, any other zeroing: since `364c5b4` the lanes' batches), `memmove` outside a sort
"memcpy": the rescue copy in builds before `09cdfaf`, which copied the particles every
10 steps; until `364c5b4` mostly the lanes' batches returned by value (2 % of the 3D
step). Start-up (seeding) and
anything before the first step is left out.

Needs perf and binutils' addr2line. Shares are of the step's samples, so of its CPU
time on one thread.
"""

import argparse
import collections
import re
import subprocess
import sys

# (regex on an inlining-chain entry, phase), checked innermost entry first.
PHASES = [
    (r"SlabOrder.*build|^build<", "slab order"),
    (r"scatter_slabs", "scatter"),
    (r"domain_weights", "domain weights"),
    (r"averaged_force|force_tiles", "averaged force"),
    (r"grid_velocity", "grid update"),
    (r"averaged_velocity_gradient|gradient_tiles", "averaged velocity gradient"),
    (r"Material::update_stress", "material stress"),
    (r"remap_slabs|^remap<", "remap"),
    (r"kernel::gather|^gather<", "gather"),
    (r"kernel::update_stress|^update_stress<", "stress update"),
    (r"relocate", "relocate"),
    (r"wrap_and_flag|locate_all|ChunkLocator|touch_runs|run_nodes|activate_tiles|slot_of_key",
     "tile pass"),
    (r"Solver.*::sort|::sort::|^sort<|permute", "sort"),
    (r"totals|strain_energy|errors<", "history totals"),
    (r"Rescue|copy_from(?!_slice)|keep<", "rescue copy"),
    (r"choose_dt|compute_max_speed", "other solver"),
    (r"run_phase", "other solver"),
    (r"Particles.*seed|with_particles|Solver.*new|^seed<|^new<", "setup"),
]
PHASES = [(re.compile(p), name) for p, name in PHASES]
TWICE = {"scatter", "domain weights", "grid update", "clear grid"}


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("data")
    ap.add_argument("--binary", default="target/release/mpmcg")
    ap.add_argument("--chains", action="store_true", help="print the unclassified chains")
    ap.add_argument("--lines", metavar="PHASE", help="the most sampled source lines of PHASE")
    ap.add_argument(
        "--within", metavar="REGEX",
        help="the share of each phase spent in inlined functions matching REGEX (e.g. 'kern<|locate')",
    )
    a = ap.parse_args()

    text = subprocess.run(
        ["perf", "script", "-i", a.data, "--show-mmap-events", "-F", "time,ip,sym,dso"],
        capture_output=True, text=True, check=True,
    ).stdout
    # The executable mapping: runtime start, file offset.
    maps = []
    samples = []  # (time, ip or None, sym)
    for line in text.splitlines():
        if "PERF_RECORD_MMAP" in line:
            m = re.search(r"\[(0x[0-9a-f]+)\((0x[0-9a-f]+)\) @ (0x[0-9a-f]+|0) .*\]: r-xp (\S+)", line)
            if m and m.group(4).endswith("/" + a.binary.split("/")[-1]):
                maps.append((int(m.group(1), 16), int(m.group(2), 16), int(m.group(3), 16)))
            continue
        m = re.match(r"\s*([\d.]+):\s+([0-9a-f]+)\s+(.*?)\s+\((.*)\)\s*$", line)
        if not m:
            continue
        t, ip, sym, dso = float(m.group(1)), int(m.group(2), 16), m.group(3), m.group(4)
        samples.append((t, ip if dso.endswith("/" + a.binary.split("/")[-1]) else None, sym))
    if not maps:
        sys.exit("no executable mapping of the binary in the profile")
    # File offset -> virtual address through the ELF program headers.
    ph = subprocess.run(["readelf", "-lW", a.binary], capture_output=True, text=True, check=True).stdout
    loads = [
        (int(f[1], 16), int(f[2], 16), int(f[4], 16))
        for f in (l.split() for l in ph.splitlines())
        if f and f[0] == "LOAD"
    ]

    def vaddr(ip):
        for start, size, pgoff in maps:
            if start <= ip < start + size:
                off = ip - start + pgoff
                for foff, va, fsz in loads:
                    if foff <= off < foff + fsz:
                        return off - foff + va
        return None

    addrs = sorted({vaddr(ip) for _, ip, _ in samples if ip is not None} - {None})
    out = subprocess.run(
        ["addr2line", "-e", a.binary, "-i", "-f", "-C", "-a"] + [hex(x) for x in addrs],
        capture_output=True, text=True, check=True,
    ).stdout
    # Per address: the inlining chain, innermost first, as (function, file, line); the
    # location printed after a function is where it called the next inner one (or, for
    # the innermost, the sampled line).
    chains = {}
    cur = None
    for line in out.splitlines():
        if line.startswith("0x"):
            cur = int(line, 16)
            chains[cur] = []
        elif line.startswith("/") or line.startswith("??"):
            if chains[cur] and chains[cur][-1][1] is None:
                f, _, ln = line.rpartition(":")
                chains[cur][-1] = (chains[cur][-1][0], f, int(ln) if ln.isdigit() else -1)
        else:
            chains[cur].append((line, None, -1))

    # The particle loops run as closures inside `kernel::par`, which addr2line names
    # `{closure#0}`: tell them apart by the lines of kernel.rs they are written on.
    spans = []
    src = None
    for ch in chains.values():
        for fn, f, ln in ch:
            if f and f.endswith("kernel.rs"):
                src = f
    if src:
        try:
            # Every top-level function starts a span (a closure of `scatter_slabs` is
            # not in `update_stress`'s), and those of the two are kept.
            starts = [
                (i + 1, m.group(1))
                for i, l in enumerate(open(src))
                for m in [re.match(r"(?:pub(?:\(crate\))? )?fn (\w+)", l)]
                if m
            ]
            for k, (ln, name) in enumerate(starts):
                end = starts[k + 1][0] if k + 1 < len(starts) else 10**9
                if name in ("gather", "update_stress"):
                    spans.append((ln, end, "gather" if name == "gather" else "stress update"))
        except OSError:
            pass

    def classify(chain):
        # Set-up last, over the whole chain: its `^new<` also names every inlined
        # constructor (the lanes' `Batch::new` in the stress pass, whose samples were
        # dropped as set-up).
        for fn, f, ln in chain:
            if fn.startswith("{closure") and f and f.endswith("kernel.rs"):
                for lo, hi, name in spans:
                    if lo <= ln < hi:
                        return name
            for rx, name in PHASES:
                if name != "setup" and rx.search(fn):
                    return name
        for fn, _, _ in chain:
            for rx, name in PHASES:
                if name == "setup" and rx.search(fn):
                    return name
        return None

    # Function start addresses, to give a sample that its chain does not place (a
    # closure without a line) the phase of most other samples of its function.
    nm = subprocess.run(["nm", "--defined-only", "-n", a.binary], capture_output=True, text=True).stdout
    starts = sorted(int(f[0], 16) for f in (l.split() for l in nm.splitlines()) if len(f) >= 3 and f[1] in "tTwW")

    def func_of(va):
        lo, hi = 0, len(starts)
        while lo < hi:
            mid = (lo + hi) // 2
            if starts[mid] <= va:
                lo = mid + 1
            else:
                hi = mid
        return starts[lo - 1] if lo else None

    sample_va = []
    labels = []
    pending = []
    votes = collections.defaultdict(collections.Counter)
    for t, ip, sym in samples:
        if ip is None:
            labels.append(None)
            continue
        va = vaddr(ip)
        sample_va.append((len(labels), va))
        ch = chains.get(va, [(sym, None, -1)])
        lab = classify(ch)
        if lab is None:
            pending.append((len(labels), func_of(va), " < ".join(f"{fn}@{ln}" for fn, _, ln in ch[:4])))
        else:
            votes[func_of(va)][lab] += 1
        labels.append(lab)
    # A helper that is not inlined (in 3D, `Geom::locate`) and other unplaced code:
    # with its neighbours in time, like the samples outside mpmcg.
    unknown = collections.Counter()
    shown = {}
    for i, fn, desc in pending:
        if votes[fn]:
            labels[i] = votes[fn].most_common(1)[0][0]
        else:
            unknown[desc] += 1
            shown[i] = desc.split(" < ")[-1].split("@")[0] + " (not inlined)"
    # Outside samples: with the previous mpmcg sample.
    prev = None
    final = []
    for i, (t, ip, sym) in enumerate(samples):
        lab = labels[i]
        if i in shown:
            sym, ip = shown[i], None
        if lab is None:
            if "memset" in sym:
                lab = "clear grid"  # the scatter's clear of the node records
            elif ("memmove" in sym or "memcpy" in sym) and prev != "sort":
                lab = "memcpy"  # see the docstring; sort's permute copies too
            else:
                lab = prev
        else:
            prev = lab
        final.append((lab, sym if ip is None else None))
    # Start at the first step; ordinals of the phases that run twice.
    first = next((i for i, (l, _) in enumerate(final) if l in ("slab order", "scatter")), 0)
    counts = collections.Counter()
    outside = collections.Counter()
    ordinal = 1
    steps = final[first:]
    for i, (lab, ext) in enumerate(steps):
        # A lone sample does not move the ordinal: helpers that several phases share
        # are given the phase of most of their samples, which may be another one.
        lone = all(steps[j][0] != lab for j in (i - 1, i + 1) if 0 <= j < len(steps))
        if lone:
            pass
        elif lab in ("gather", "remap", "stress update", "material stress"):
            ordinal = 2
        elif lab in ("relocate", "tile pass", "sort", "rescue copy", "memcpy", "history totals"):
            ordinal = 1
        if lab in TWICE:
            lab = f"{lab} ({ordinal})"
        if lab is None or lab == "setup":
            continue
        counts[lab] += 1
        if ext:
            outside[(lab, ext)] += 1
    total = sum(counts.values())
    print(f"{total} samples after start-up")
    for lab, c in counts.most_common():
        print(f"{100.0 * c / total:6.1f} %  {lab}")
    print("outside mpmcg's code (included above):")
    for (lab, sym), c in outside.most_common(12):
        print(f"{100.0 * c / total:6.1f} %  {sym} -> {lab}")
    if a.within:
        rx = re.compile(a.within)
        inside = collections.Counter()
        per = collections.Counter()
        for i, va in sample_va:
            if i < first or labels[i] in (None, "setup"):
                continue
            per[labels[i]] += 1
            if any(rx.search(fn) for fn, _, _ in chains.get(va, [])):
                inside[labels[i]] += 1
        n_in = sum(inside.values())
        print(f"in /{a.within}/: {100.0 * n_in / total:.1f} % of the step's samples")
        for lab, c in per.most_common():
            if inside[lab]:
                print(f"{100.0 * inside[lab] / c:6.1f} % of {lab}")
    if a.lines:
        where = collections.Counter()
        for i, va in sample_va:
            if labels[i] == a.lines.split(" (")[0]:
                ch = chains.get(va, [])
                # The innermost line in src/ and the function it is in.
                for fn, f, ln in ch:
                    if f and "/src/" in f and "/rustc/" not in f:
                        where[f"{f.split('/src/')[-1]}:{ln} ({fn.split('<')[0]})"] += 1
                        break
                else:
                    where["?"] += 1
        n_lab = sum(where.values())
        print(f"lines of {a.lines} ({n_lab} samples):")
        for w, c in where.most_common(25):
            print(f"{100.0 * c / n_lab:6.1f} %  {w}")
    if a.chains:
        for ch, c in unknown.most_common(15):
            print(c, ch)


if __name__ == "__main__":
    main()
