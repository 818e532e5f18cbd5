"""Parts of the source tree that gonio finds through package metadata, never by importing them by name.

docs/architecture.md §1: ``gonio`` never imports ``sim``; the simulator is selected through configuration. The
command line's ``--sim`` switches and ``gonio bench`` find the simulator and the benchmarks through
the entry points ``pyproject.toml`` declares (``[project.entry-points."gonio.plugins"]``), so the
dependency points from ``sim`` to ``gonio`` only, and an installation without them says so in one line.
"""

from __future__ import annotations

from gonio.errors import ConfigError

__all__ = ["plugin"]

GROUP = "gonio.plugins"


#: The plugins loaded in this process, by name: a lookup reads every installed distribution's metadata (~2.5 ms
#: warm, more cold), and a simulated session asks for ``sim.rig`` several times (open, check, resume)
_LOADED: dict = {}


def plugin(name: str):
    """The module registered as ``name`` in the ``gonio.plugins`` entry-point group (e.g. ``sim.rig``); looked up
    once per process (a module once imported stays in ``sys.modules`` anyway); one not found is looked up again."""
    if name in _LOADED:
        return _LOADED[name]
    from importlib.metadata import entry_points

    found = [ep for ep in entry_points(group=GROUP) if ep.name == name]
    if not found:
        raise ConfigError(f"{name}: not installed (the simulator and the benchmarks come with the gonio source "
                          f"tree: pip install -e . in a checkout)")
    _LOADED[name] = module = found[0].load()
    return module
