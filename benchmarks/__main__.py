"""``python -m benchmarks [--quick] [NAME ...]``: run benchmark modules and print their tables."""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import platform
import sys
import time
from pathlib import Path

import benchmarks


def available() -> list[str]:
    here = Path(benchmarks.__file__).parent
    return sorted(m.name[len("bench_"):] for m in pkgutil.iter_modules([str(here)]) if m.name.startswith("bench_"))


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__)
    p.add_argument("names", nargs="*", help=f"benchmarks to run (default all): {', '.join(available())}")
    p.add_argument("--quick", action="store_true", help="small sizes, for CI")
    args = p.parse_args(argv)
    names = args.names or available()
    unknown = sorted(set(names) - set(available()))
    if unknown:
        print(f"python -m benchmarks: error: unknown benchmark {unknown[0]!r}; known: {', '.join(available())}",
              file=sys.stderr)
        return 2
    print(f"# gonio benchmarks ({'quick' if args.quick else 'full'}) — {platform.processor() or platform.machine()}, "
          f"Python {platform.python_version()}, {time.strftime('%Y-%m-%d')}\n")
    for name in names:
        start = time.perf_counter()
        tables = importlib.import_module(f"benchmarks.bench_{name}").run(quick=args.quick)
        for t in tables:
            print(t.to_markdown())
        print(f"_{name}: {time.perf_counter() - start:.1f} s_\n", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
