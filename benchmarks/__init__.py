"""gonio's benchmarks: speed and accuracy trade-offs, each against a baseline measured in the same run.

Run them all with ``python -m benchmarks`` (``--quick`` for a short run; names to select, e.g.
``python -m benchmarks brdf protocol``). Each ``bench_<name>.py`` module defines
``run(quick: bool) -> list[Table]``.
"""
