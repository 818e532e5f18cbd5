"""Material files: which BRDF the simulated sample carries (and the label a session records).

A material file is TOML::

    label = "red plastic"            # optional, free text
    model = "microfacet"             # a gonio.brdf model name (gonio models lists them)
    [params]                         # that model's parameters; RGB as 3-element arrays
    kd = [0.3, 0.1, 0.05]
    ks = 1.0
    alpha = 0.2
    f0 = 0.04
    distribution = "ggx"

Every error is a :class:`gonio.errors.ConfigError` whose one-line message names the file, the field
and the value (the model's own parameter checks name them too, through ``make(..., source=file)``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from gonio.errors import ConfigError

try:  # Python >= 3.11
    import tomllib
except ModuleNotFoundError:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = ["Material", "load_material", "material_from_dict"]

_KEYS = {"label", "model", "params"}


@dataclass(frozen=True)
class Material:
    """A parsed material: model name, parameters (as written, JSON-able), label, where it came from."""

    model: str
    params: Mapping[str, Any] = field(default_factory=dict)
    label: str = ""
    source: str = "<material>"

    def brdf(self):
        """The :class:`gonio.brdf.base.BRDF` object (validates the parameters)."""
        from gonio.brdf import make

        return make(self.model, source=self.source, **dict(self.params))

    def to_dict(self) -> dict[str, Any]:
        """``{"model", "params", "label"}``: what the session manifest records."""
        return {"model": self.model, "params": dict(self.params), "label": self.label}


def material_from_dict(data: Mapping[str, Any], source: str = "<material>") -> Material:
    """Check a parsed material table and build the BRDF once (so bad parameters fail here)."""
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
    label = data.get("label", "")
    if not isinstance(label, str):
        raise ConfigError.field(source, "label", label, "must be a string")
    m = Material(model=model, params=dict(params), label=label or model, source=source)
    m.brdf()  # unknown model, missing or bad parameter -> ConfigError naming source and field
    return m


def load_material(path: str | Path) -> Material:
    """Read and check a material TOML file."""
    p = Path(path)
    src = str(p)
    try:
        text = p.read_text(encoding="utf-8")
    except OSError as exc:
        raise ConfigError.field(None, "--material", src, f"cannot read: {exc.strerror or exc}") from None
    try:
        data = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise ConfigError(f"{src}: not valid TOML: {exc}") from None
    return material_from_dict(data, src)
