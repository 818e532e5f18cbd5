"""The ``gonio`` command. One module per subcommand; :mod:`gonio.cli.main` dispatches.

Each subcommand module defines ``register(subparsers)`` (adds its parser and sets
``func=run``) and ``run(args) -> int``. Modules import heavy dependencies (cv2, scipy.optimize,
matplotlib) inside ``run`` only, so ``gonio --help`` stays fast.
"""
