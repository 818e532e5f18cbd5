"""``gonio bench``: the speed-versus-accuracy report.

Runs every trade gonio offers between speed and accuracy (plan density and kind, exposure bracket and
frames, Schlick vs pow and float32 vs float64, MERL interpolation, fit subsampling) on the simulated
rig and on this machine, and writes ``DIR/REPORT.md`` with tables and PNG plots
(:mod:`benchmarks.report`). Like ``gonio measure --sim`` this is a configuration boundary: the
benchmark code (which drives the simulator) is imported lazily, only when the command runs.
"""

from __future__ import annotations

import sys
import time


def register(sub) -> None:
    p = sub.add_parser("bench", help="speed-versus-accuracy report (Markdown + PNG plots)",
                       description="Measure each speed/accuracy trade against a baseline from the same run and "
                                   "write DIR/REPORT.md with tables (default marked, with its reason), the date, "
                                   "the machine and the run's duration, and one PNG plot per trade.")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="small sizes (for CI): well under two minutes")
    size.add_argument("--smoke", action="store_true",
                      help="every trade at its smallest size, seconds: checks that the report runs end to end on "
                           "this machine (its numbers mean little)")
    p.add_argument("--robustness", action="store_true",
                   help="instead: the robustness benchmark (fuzzed frames and status packets, mutated configs and "
                        "session files, kill -9 + resume, fault scenarios), at full scale unless --quick; "
                        "writes DIR/ROBUSTNESS.md")
    p.add_argument("-o", "--out", default="gonio-bench", metavar="DIR",
                   help="output directory (default ./gonio-bench; REPORT.md and the PNGs are overwritten)")
    p.set_defaults(func=run)


def run(args) -> int:
    from pathlib import Path

    from gonio.errors import ConfigError

    out = Path(args.out)
    if out.exists() and not out.is_dir():
        raise ConfigError.field("-o", "out", str(out), "exists and is not a directory")
    from gonio.plugins import plugin

    t0 = time.perf_counter()
    if args.robustness:
        path = plugin("benchmarks.report").write_robustness(out, quick=args.quick or args.smoke, stream=sys.stdout)
        print(f"{path} ({time.perf_counter() - t0:.0f} s)")
        return 0
    write_report = plugin("benchmarks.report").write_report
    sizes = plugin("benchmarks.report").Size  # benchmarks.common.Size

    size = sizes.SMOKE if args.smoke else sizes.QUICK if args.quick else sizes.FULL
    path, failed = write_report(out, quick=size, stream=sys.stderr)
    print(f"{path} ({time.perf_counter() - t0:.0f} s)")
    if failed:
        print(f"gonio bench: error: {len(failed)} trade(s) failed: {', '.join(failed)} (see {path})", file=sys.stderr)
        return 1
    return 0
