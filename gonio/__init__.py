"""gonio — run a gonioreflectometer, simulate it, and turn its measurements into BRDFs.

The Python API (see the README's "Python API" section and ``docs/``)::

    import gonio
    data = gonio.load("session-dir")            # or a MERL .binary, a gonio .npz / .csv export, ...
    result = gonio.fit(data, "lambert+ggx")     # one model; gonio.select(data) chooses among several
    print(result)                               # parameter table with uncertainties
    result.model.eval(wi, wo)                   # the fitted BRDF, evaluable (1/sr, RGB)
    gonio.render_sphere(result.model, [gonio.light_from_angles(35)])   # a lit sphere (shows in a notebook)

    with gonio.open_rig(sim=True) as rig:        # the simulated rig, or a rig's files and ports
        run = gonio.measure(rig, "half_diff", "session-dir", on_pose=print)

Subpackages: :mod:`gonio.geometry`, :mod:`gonio.lights` and :mod:`gonio.brdf` are the pure physics
core; :mod:`gonio.rig` talks to hardware; :mod:`gonio.pipeline`, :mod:`gonio.plan` and
:mod:`gonio.session` acquire; :mod:`gonio.io`, :mod:`gonio.tabulate` and :mod:`gonio.fit` handle data.
The architecture is described in ``docs/architecture.md``, every file format in ``docs/formats.md``.

``gonio.fit`` is both the fitting subpackage and, called, :func:`gonio.api.fit`. Names are imported
on first use, so ``import gonio`` stays cheap.
"""

__version__ = "0.1.0"

#: Public names and the module that defines each (imported lazily, PEP 562).
_API = {
    "load": "gonio.api", "select": "gonio.api", "as_samples": "gonio.api",
    "Measured": "gonio.io.source", "SampleSet": "gonio.samples", "FitResult": "gonio.fit.result",
    "Selection": "gonio.fit.select", "make": "gonio.brdf", "MODELS": "gonio.brdf",
    "render_sphere": "gonio.render", "light_from_angles": "gonio.render",
    # renderer exports of a fit, one shape for all (defined in gonio.io: the formats depend on the fit)
    "to_mitsuba": "gonio.io.exports", "to_pbrt": "gonio.io.exports", "to_gltf": "gonio.io.exports",
    # the instrument: open a rig, measure a plan, resume a session (gonio.session.api)
    "open_rig": "gonio.session.rigs", "measure": "gonio.session.api", "resume": "gonio.session.api",
    "SessionResult": "gonio.session.api", "PoseEvent": "gonio.session.runner",
    "SimOptions": "gonio.session.options", "HardwareOptions": "gonio.session.options",
    "TimingOptions": "gonio.session.options",
}

__all__ = ["fit", *_API]


def __getattr__(name):
    if name == "fit":  # the subpackage, callable (gonio/fit/__init__.py)
        import importlib

        return importlib.import_module("gonio.fit")
    module = _API.get(name)
    if module is None:
        raise AttributeError(f"module 'gonio' has no attribute {name!r}")
    import importlib

    return getattr(importlib.import_module(module), name)


def __dir__():
    return sorted(set(globals()) | set(__all__))
