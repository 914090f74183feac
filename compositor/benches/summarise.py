#!/usr/bin/env python3
"""Summarises `cargo bench -p lightfold-compositor --bench operators` (criterion's estimates
under target/criterion) as the markdown table of docs/operators.md: Mpixel/s, GB/s of bytes read
plus written, the fraction of memcpy bandwidth moving the same bytes in the same run, and the fast
version's speed-up over the scalar reference. Rows of a filtered run that measured nothing, and
the per-instruction-set rows this CPU cannot run, are left out."""
import json
import os
import sys

ROOT = os.path.join(os.path.dirname(__file__), "..", "..", "target", "criterion")
# Bytes read + written per pixel, and the memcpy benchmark that moves the same amount.
MOVED = {
    "accumulate": 72,
    "accumulate_rgb9e5x2_fused": 40,
    "accumulate_rgb9e5x2_fused_avx2": 40,
    "accumulate_rgb9e5x2_fused_baseline": 40,
    "accumulate_rgb9e5x2_unpack_then_apply": 40,
    "accumulate_seed64_fused": 40,
    "accumulate_seed64_fused_avx2": 40,
    "accumulate_seed64_fused_baseline": 40,
    "accumulate_seed64_unpack_then_apply": 40,
    "accumulate_f16x6_rgb9e5x2_fused": 44,
    "material": 48,
    "depth": 84,
    "join": 72,
    "output": 24,
    "srgb8": 15,
}


def mean_ns(group, name):
    """The fastest sample's time per iteration, in ns. The machine is shared: the fastest of the
    ten samples is the least disturbed one, for the operators and memcpy alike."""
    path = os.path.join(ROOT, group, name, "new", "sample.json")
    with open(path) as f:
        s = json.load(f)
    return min(t / n for t, n in zip(s["times"], s["iters"]))


def main():
    groups = sorted(g for g in os.listdir(ROOT) if g.startswith("ops_"))
    sizes = sorted({g.rsplit("_", 1)[0] for g in groups}, key=lambda s: -eval(s[4:].replace("x", "*")))
    print("| size | operator | 1 thread Mpx/s | GB/s | % memcpy | all cores Mpx/s | GB/s | % memcpy | fast ÷ scalar |")
    print("|---|---|---|---|---|---|---|---|---|")
    for size in sizes:
        w, h = size[len("ops_"):].split("x")
        px = int(w) * int(h)
        threads = sorted(g for g in groups if g.startswith(size + "_"))
        for name, moved in MOVED.items():
            if not all(os.path.exists(os.path.join(ROOT, g, name)) for g in threads):
                continue
            cells = []
            for g in threads:
                t = mean_ns(g, name)
                m = mean_ns(g, f"memcpy_{moved}B")
                mpx = px / t * 1e3
                cells += [f"{mpx:.0f}", f"{moved * px / t:.1f}", f"{100 * m / t:.0f} %"]
            try:
                speedup = f"{mean_ns(threads[0], name + '_scalar') / mean_ns(threads[0], name):.1f}×"
            except FileNotFoundError:
                speedup = "—"
            print(f"| {w}×{h} | {name} | " + " | ".join(cells) + f" | {speedup} |")
    print()
    print("| size | memcpy bytes/px | 1 thread GB/s | all cores GB/s |")
    print("|---|---|---|---|")
    for size in sizes:
        w, h = size[len("ops_"):].split("x")
        px = int(w) * int(h)
        threads = sorted(g for g in groups if g.startswith(size + "_"))
        for moved in sorted(set(MOVED.values())):
            if not all(os.path.exists(os.path.join(ROOT, g, f"memcpy_{moved}B")) for g in threads):
                continue
            gbs = [f"{moved * px / mean_ns(g, f'memcpy_{moved}B'):.1f}" for g in threads]
            print(f"| {w}×{h} | {moved} | " + " | ".join(gbs) + " |")


if __name__ == "__main__":
    sys.exit(main())
