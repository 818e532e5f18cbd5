"""gonio — run a gonioreflectometer, simulate it, and turn its measurements into BRDFs.

Subpackages (see ``DESIGN.md``): :mod:`gonio.geometry`, :mod:`gonio.lights` and :mod:`gonio.brdf`
are the pure physics core; :mod:`gonio.rig` talks to hardware; :mod:`gonio.pipeline`,
:mod:`gonio.plan` and :mod:`gonio.session` acquire; :mod:`gonio.io`, :mod:`gonio.tabulate` and
:mod:`gonio.fit` handle data.
"""

__version__ = "0.1.0"
