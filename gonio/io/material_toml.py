"""Material files: which BRDF the simulated sample carries (and the label a session records).

A material file is TOML (a measured material or a fitted model is a data file: :mod:`gonio.io.material_file`)::

    label = "red plastic"            # optional, free text
    model = "microfacet"             # a gonio.brdf model name (gonio models lists them)
    [params]                         # that model's parameters; RGB as 3-element arrays
    kd = [0.3, 0.1, 0.05]
    ks = 1.0
    alpha = 0.2
    f0 = 0.04
    distribution = "ggx"

A sum of lobes names its parameters ``lobe.param``; dotted keys (``diffuse.albedo = 0.3``, i.e. nested
tables, at any depth) and quoted keys (``"diffuse.albedo" = 0.3``) are the same.

A parameter left out takes the model's default (``gonio models`` lists them) — never silently:
:attr:`Material.defaulted` names them, ``gonio measure`` prints them, and the manifest records the
complete parameter set the sample was simulated with. A parameter without a default must be given.
Every error is a :class:`gonio.errors.ConfigError` whose one-line message names the file, the
field(s) and the value: missing and unknown parameters are listed all at once; types and ranges are
the model's own checks (``make(..., source=file)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from gonio.config import read_toml
from gonio.errors import ConfigError


__all__ = ["Material", "load_material", "material_from_dict", "describe_material"]

_KEYS = {"label", "model", "params"}


@dataclass(frozen=True)
class Material:
    """A parsed material: model name, parameters (as written, JSON-able), label, where it came from."""

    model: str
    params: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""
    source: str = "<material>"
    #: Parameters the file left out, filled with the model's defaults (already in ``params``).
    defaulted: tuple[str, ...] = ()

    def defaults_note(self) -> str:
        """One line naming the defaulted parameters and their values ('' when the file gave all)."""
        if not self.defaulted:
            return ""
        vals = ", ".join(f"{k} = {self.params[k]}" for k in self.defaulted)
        return f"material {self.source}: not given, the model's defaults are used: {vals}"

    def brdf(self):
        """The :class:`gonio.brdf.base.BRDF` object (validates the parameters)."""
        from gonio.brdf import make

        return make(self.model, source=self.source, **dict(self.params))

    def to_dict(self) -> dict[str, Any]:
        """``{"model", "params", "label"}``: what the session manifest records."""
        return {"model": self.model, "params": dict(self.params), "label": self.label}


def _model_params(model: str, source: str) -> dict:
    """The parameter specs of the model registered as ``model`` (unknown model: ConfigError from make)."""
    from gonio.brdf import MODELS, is_sum_name, lobe_sum, make

    cls = MODELS.get(model)
    if cls is None and is_sum_name(model):
        try:
            cls = lobe_sum(model)
        except ConfigError:
            cls = None
    if cls is None:
        make(model, source=source)  # raises the registry's one-line error naming the model
    return dict(cls.PARAMS)


def _flatten(params: Mapping[str, Any], source: str, prefix: str = "") -> dict[str, Any]:
    """Nested tables to dotted names, at any depth: TOML's ``diffuse.albedo = 0.3`` (a table ``diffuse``)
    becomes the lobe-sum parameter ``"diffuse.albedo"``, as the quoted key ``"diffuse.albedo" = 0.3`` is."""
    out: dict[str, Any] = {}
    for key, value in params.items():
        name = f"{prefix}{key}"
        items = _flatten(value, source, f"{name}.") if isinstance(value, Mapping) else {name: value}
        for k, v in items.items():
            if k in out:
                raise ConfigError.field(source, f"params.{k}", v, "given twice (as a dotted and a quoted key)")
            out[k] = v
    return out


def material_from_dict(data: Mapping[str, Any], source: str = "<material>", *, complete: bool = True) -> Material:
    """Check a parsed material table and build the BRDF once (so bad parameters fail here).

    Parameters left out take the model's defaults and are listed in :attr:`Material.defaulted`
    (``complete``: a parameter without a default is an error; ``complete=False`` leaves that to the
    model, for materials recorded by older sessions).
    """
    if not isinstance(data, Mapping):
        raise ConfigError.field(source, "material", data, "must be a table")
    unknown = sorted(set(data) - _KEYS)
    if unknown:
        raise ConfigError.field(source, unknown[0], data[unknown[0]], f"unknown field; a material has {', '.join(sorted(_KEYS))}")
    if "model" not in data:
        raise ConfigError.field(source, "model", None, "missing (a gonio.brdf model name, see `gonio models`)")
    model = data["model"]
    if not isinstance(model, str) or not model:
        raise ConfigError.field(source, "model", model, "must be a model name (string)")
    params = data.get("params", {})
    if not isinstance(params, Mapping):
        raise ConfigError.field(source, "params", params, "must be a table of the model's parameters")
    params = _flatten(params, source)
    label = data.get("label", "")
    if not isinstance(label, str):
        raise ConfigError.field(source, "label", label, "must be a string")
    specs = _model_params(model, source)
    names = tuple(specs)
    unknown = [k for k in params if k not in names]
    if unknown:
        raise ConfigError(f"{source}: params: unknown parameter{'s' if len(unknown) > 1 else ''} "
                          f"{', '.join(unknown)} (model {model!r} takes {', '.join(names)})")
    required = [k for k in names if k not in params and specs[k].default is None]
    if required and complete:
        raise ConfigError(f"{source}: params: missing {', '.join(required)} (no default in model {model!r}, "
                          f"which takes {', '.join(names)})")
    defaulted = tuple(k for k in names if k not in params and specs[k].default is not None)
    full = {**params, **{k: specs[k].default for k in defaulted}}
    full = {k: full[k] for k in names if k in full}  # the model's order
    m = Material(model=model, params=full, label=label or model, source=source, defaulted=defaulted)
    m.brdf()  # unknown model, missing or bad parameter -> ConfigError naming source and field
    return m


def load_material(path: str | Path) -> Material:
    """Read and check a material TOML file."""
    return material_from_dict(read_toml(path, "--material"), str(path))


def describe_material(m) -> str:
    """A manifest's material for people: ``label (model: name = value, ...)``."""
    if not isinstance(m, dict) or not m:
        return "unknown"
    if isinstance(m.get("file"), str):  # a measured material or a fitted model (gonio/io/material_file.py)
        digest = f", sha256 {m['sha256'][:12]}…" if isinstance(m.get("sha256"), str) else ""
        return f"{m.get('label') or m['file']} ({m.get('kind') or 'file'} {m['file']}{digest})"
    label, model = m.get("label") or "", m.get("model")
    params = m.get("params") if isinstance(m.get("params"), dict) else {}

    def fmt(v):
        if isinstance(v, list):
            return "(" + ", ".join(fmt(x) for x in v) + ")"
        return f"{v:.4g}" if isinstance(v, float) else str(v)

    inner = ", ".join(f"{k} = {fmt(v)}" for k, v in params.items())
    if not isinstance(model, str):
        return label or "unknown"
    body = f"{model}: {inner}" if inner else model
    return f"{label} ({body})" if label and label != model else body
