"""Renderer exports of a fit, one shape for all three: ``to_mitsuba``, ``to_pbrt``, ``to_gltf``.

Each takes a fit (:class:`gonio.fit.result.FitResult`, a :class:`gonio.fit.select.Selection`, what
:func:`gonio.load` reads from a fit JSON) or a model (:func:`gonio.brdf.make`), ``path`` (also write the file
there: checked as every output is, :func:`gonio.io.outputs.check_output`; an existing file only with
``force``) and ``approx``; it returns the material as the renderer's own Python interface takes it:

- :func:`to_mitsuba`: the BSDF dictionary of ``mitsuba.load_dict`` (:mod:`gonio.io.mitsuba`; a ``path`` ending
  in ``.xml`` gets the scene-file element, else the dictionary as JSON);
- :func:`to_pbrt`: the pbrt-v4 scene text (:mod:`gonio.io.pbrt`);
- :func:`to_gltf`: the glTF 2.0 document as a dictionary, a sphere with the material (:mod:`gonio.io.gltf`).

A model the renderer cannot reproduce within its tolerance is refused in one :class:`gonio.errors.ConfigError`
line naming why and the error, unless ``approx=True`` (the closest material; its error is
:attr:`gonio.io.approx.Exported.error`). These live in ``io``, not on the fit result: the data formats depend
on the fit, not the reverse (docs/architecture.md §1).
"""

from __future__ import annotations

import json
from pathlib import Path

from gonio.errors import ConfigError

__all__ = ["to_mitsuba", "to_pbrt", "to_gltf", "exported"]

#: File name endings each renderer's file may have.
SUFFIXES = {"mitsuba": (".xml", ".json"), "pbrt": (".pbrt",), "gltf": (".gltf",)}


def _model(fit):
    """The evaluable model of a fit result, a selection or a model itself."""
    model = getattr(fit, "model", fit)
    if not callable(getattr(model, "eval", None)):
        raise TypeError(f"expected a fit result or a gonio.brdf model, not {type(fit).__name__}")
    return model


def exported(fit, renderer: str, path=None, *, approx: bool = False):
    """The :class:`gonio.io.approx.Exported` of ``fit`` for ``renderer`` (``mitsuba``, ``pbrt``, ``gltf``),
    checked (exact, within tolerance, or ``approx``); the refusal names the keyword ``approx=True``."""
    model = _model(fit)
    try:
        if renderer == "mitsuba":
            from gonio.io.mitsuba import mitsuba_export

            return mitsuba_export(model, None if path is None else Path(path), approx=approx, option="approx")
        if renderer == "pbrt":
            from gonio.io.pbrt import to_pbrt as pbrt_text

            ex = pbrt_text(model, name=Path(path).stem if path is not None else "gonio", approx=approx)
        elif renderer == "gltf":
            from gonio.io.gltf import to_gltf as gltf_text

            ex = gltf_text(model, name=Path(path).stem if path is not None else "gonio material", approx=approx)
        else:
            raise ValueError(f"renderer = {renderer!r}: one of {', '.join(SUFFIXES)}")
        return ex.check(approx, "approx")
    except ConfigError as exc:  # the refusal names the CLI's option; in Python it is the keyword
        raise ConfigError(str(exc).replace("--approx", "approx=True")) from None


def _export(fit, renderer: str, path, approx: bool, force: bool):
    if path is not None:
        from gonio.io.outputs import check_output

        path = check_output(path, option="path", force=force, suffixes=SUFFIXES[renderer])
    ex = exported(fit, renderer, path, approx=approx)
    if path is not None:
        ex.write(path, "path")
    return ex


def to_mitsuba(fit, path=None, *, approx: bool = False, force: bool = False) -> dict:
    """The Mitsuba 3 BSDF dictionary (``mitsuba.load_dict``) of ``fit`` (module docstring); also written to
    ``path`` (``.xml``: the scene-file element; ``.json``: the dictionary)."""
    ex = _export(fit, "mitsuba", path, approx, force)
    if path is not None and Path(path).suffix.lower() == ".xml":
        ex = exported(fit, "mitsuba", None, approx=approx)  # the dictionary, not the XML written
    return json.loads(ex.text)


def to_pbrt(fit, path=None, *, approx: bool = False, force: bool = False) -> str:
    """The pbrt-v4 material text of ``fit`` (module docstring); also written to ``path`` (``.pbrt``)."""
    return _export(fit, "pbrt", path, approx, force).text


def to_gltf(fit, path=None, *, approx: bool = False, force: bool = False) -> dict:
    """The glTF 2.0 document (a sphere with the material) of ``fit`` as a dictionary (module docstring); also
    written to ``path`` (``.gltf``)."""
    return json.loads(_export(fit, "gltf", path, approx, force).text)
