"""How far results move on x86-64 CPUs without AVX2 and FMA (before ~2013), where glibc picks
other libm routines and MuJoCo's floats differ in the last bits, and Mesa's llvmpipe draws
camera frames with other vector code.

    python benchmarks/old_cpus.py [--heldout 200]   # writes benchmarks/results/old_cpus.{md,json}

Each policy's base, zero ticket and bundled golden tickets run on the same held-out seeds twice,
in subprocesses: natively, and with glibc told that the CPU lacks AVX2 and FMA
(GLIBC_TUNABLES=glibc.cpu.hwcaps=-AVX2,-FMA) and llvmpipe told it has SSE4.1 at most
(GALLIUM_OVERRIDE_CPU_CAPS=sse4.1; it draws the image policy's frames). Every other kernel
choice (MKL, ATen, numpy) leaves episodes identical: tests/test_numerics.py.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).parent
POLICIES = ("metaworld/pick-place-v3/flow", "metaworld/reach-v3/ddim@2",
            "metaworld-pixels/drawer-open-v3/flow")
OLD_CPU = {"GLIBC_TUNABLES": "glibc.cpu.hwcaps=-AVX2,-FMA", "GALLIUM_OVERRIDE_CPU_CAPS": "sse4.1"}
EPISODES = """
import json, sys
import goldenticket
from goldenticket.policies import bundled_tickets
from goldenticket.tasks import seeds_in

from goldenticket.tickets import Ticket

policy, n = sys.argv[1], int(sys.argv[2])
tickets = [path for path in bundled_tickets() if Ticket.load(path).metadata["policy"] == policy]
task = "/".join(policy.split("/")[:2])
rows = goldenticket.evaluate(policy, task, tickets, seeds_in("heldout", n), workers=2)
print(json.dumps({label: row.successes for label, row in rows.items()}))
"""


def outcomes(policy: str, n: int, env: dict[str, str]) -> dict[str, list[bool]]:
    proc = subprocess.run([sys.executable, "-c", EPISODES, policy, str(n)], env=os.environ | env,
                          capture_output=True, text=True, check=True)
    return json.loads(proc.stdout)


def compare(policy: str, n: int) -> dict:
    native, old = outcomes(policy, n, {}), outcomes(policy, n, OLD_CPU)
    return {arm: {"native": sum(native[arm]) / n, "old_cpu": sum(old[arm]) / n,
                  "episodes_differing": sum(a != b for a, b in zip(native[arm], old[arm], strict=True))}
            for arm in native}


def markdown(results: dict, n: int) -> str:
    lines = ["| policy | arm | success, AVX2 + FMA | success, without | episodes differing |",
             "|---|---|---|---|---|"]
    for policy, arms in results.items():
        for arm, r in arms.items():
            lines.append(f"| {policy} | {arm} | {r['native']:.1%} | {r['old_cpu']:.1%} | "
                         f"{r['episodes_differing']} of {n} |")
    return "\n".join(lines) + "\n"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--heldout", type=int, default=200, help="held-out seeds per arm")
    args = parser.parse_args()
    results = {policy: compare(policy, args.heldout) for policy in POLICIES}
    out = HERE / "results"
    (out / "old_cpus.json").write_text(json.dumps({"heldout": args.heldout, "env": OLD_CPU,
                                                   "results": results}, indent=2) + "\n")
    (out / "old_cpus.md").write_text(markdown(results, args.heldout))
    print(markdown(results, args.heldout))


if __name__ == "__main__":
    main()
