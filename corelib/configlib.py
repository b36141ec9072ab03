"""Strict, typed configuration shared by `synth` and `mcdp`.

Every component has one frozen pydantic model; all defaults live in those
models, a YAML preset only lists what differs, and the command line overrides
single keys with dotted paths::

    synth render configs/data/tiny.yaml --out DATA rig.overlap=0.3 camera.width=160

Unknown keys, wrong types and out-of-range values are errors that name the
dotted key and say what is allowed (`ConfigError`). Nothing is coerced
silently: the string "3" is not an int, 1.5 is not an int.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Any, Iterable, Type, TypeVar

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from corelib.hashing import json_sha256
from corelib.readfile import ReadRefused, read_text_file

T = TypeVar("T", bound="StrictModel")

#: the checkout's root: presets named relative to it are found from any working directory
PROJECT_ROOT = Path(__file__).resolve().parents[1]


class ConfigError(ValueError):
    """A configuration value, key or file is invalid; the message names it."""


def env_int(name: str, default: int, lo: int, hi: int, hint: str = "") -> int:
    """The integer value of environment variable `name` (`default` when unset or empty); ConfigError naming the
    variable, its value cut and escaped, when it is not an integer in [lo, hi] (`hint`: what to do instead)."""
    import os

    text = os.environ.get(name, "")
    if not text.strip():
        return default
    try:
        value = int(text.strip())
    except ValueError:
        value = None
    if value is None or not lo <= value <= hi:
        raise ConfigError(f"environment variable {name}={text[:40]!r} must be an integer in [{lo}, {hi}]"
                          + (f"; {hint}" if hint else ""))
    return value


class StrictModel(BaseModel):
    """Base for every config section: frozen, unknown keys forbidden, no coercion."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, validate_default=True)

    def hashed_form(self, d: dict[str, Any]) -> dict[str, Any]:
        """What `config_hash` hashes of this section, given its plain dict `d` (after the `added_key` keys at
        their default are left out): `d` itself. A section overrides it only to keep the hash of a key whose
        form changed while what it makes did not (`scenes.config.SceneConfig.family_weights`)."""
        return d


#: at most this many problems of one config are listed (the rest counted), each value echoed to `_ECHO` chars
MAX_ERROR_LINES = 8
_ECHO = 80


def _format_validation_error(err: ValidationError, source: str) -> str:
    lines = []
    errors = err.errors()
    for e in errors[:MAX_ERROR_LINES]:
        key = ".".join(str(p) for p in e["loc"]) or "<root>"
        if e["type"] == "extra_forbidden":
            msg = "unknown key"
        elif e["type"] == "value_error":  # a validator's own sentence, without pydantic's "Value error, "
            msg = str(e.get("ctx", {}).get("error", e["msg"]))
        else:
            msg = e["msg"]
        got = e.get("input")
        # a validator's sentence that already says what it got is not echoed a second time
        echoed = isinstance(got, dict) or (e["type"] == "value_error" and "got " in msg)
        got_s = "" if echoed else f" (got {_cut(repr(got))})"
        lines.append(f"  {_cut(key)}: {_cut(msg, 400)}{got_s}")
    if len(errors) > MAX_ERROR_LINES:
        lines.append(f"  (+{len(errors) - MAX_ERROR_LINES} more)")
    return f"invalid config ({_cut(source, 300)}):\n" + "\n".join(lines)


def _cut(text: str, limit: int = _ECHO) -> str:
    return text if len(text) <= limit else text[:limit] + "..."


class _Loader(yaml.SafeLoader):
    """SafeLoader that also reads ``1e-4`` / ``3E5`` as floats (YAML 1.2; PyYAML's 1.1
    resolver needs a dot, so ``lr: 1e-4`` would otherwise arrive as a string)."""


_Loader.add_implicit_resolver(
    "tag:yaml.org,2002:float",
    re.compile(r"""^(?:[-+]?(?:[0-9][0-9_]*)\.[0-9_]*(?:[eE][-+]?[0-9]+)?
                 |[-+]?(?:[0-9][0-9_]*)(?:[eE][-+]?[0-9]+)
                 |\.[0-9_]+(?:[eE][-+]?[0-9]+)?
                 |[-+]?\.(?:inf|Inf|INF)
                 |\.(?:nan|NaN|NAN))$""", re.X),
    list("-+0123456789."),
)


#: the largest config file read (bytes); presets are a few KB
MAX_CONFIG_BYTES = 1 << 20


#: the deepest nesting of mappings and lists a config may have (presets: 3), counting the parts of a dotted
#: override key; deeper would exhaust the composer's recursion with a traceback of thousands of lines
MAX_CONFIG_DEPTH = 32

#: the most keys and list items a config may hold at all depths together, a file, the overrides or both
#: merged (presets: at most 54; a resolved run config: about 60)
MAX_CONFIG_KEYS = 10_000


def check_bounds(data: Any, source: str) -> None:
    """ConfigError naming ``source`` when ``data`` (a parsed config) is nested more than `MAX_CONFIG_DEPTH`
    levels or holds more than `MAX_CONFIG_KEYS` keys and list items; walked without recursion."""
    entries, stack = 0, [(data, 1)]
    while stack:
        node, depth = stack.pop()
        if isinstance(node, dict):
            children = list(node.values())
        elif isinstance(node, (list, tuple)):
            children = list(node)
        else:
            continue
        if depth > MAX_CONFIG_DEPTH:
            raise ConfigError(f"{_cut(source, 300)}: nested more than {MAX_CONFIG_DEPTH} levels deep; a config is a "
                              "few levels deep")
        entries += len(children)
        if entries > MAX_CONFIG_KEYS:
            raise ConfigError(f"{_cut(source, 300)}: more than {MAX_CONFIG_KEYS} keys and list items; a config has "
                              "a few dozen")
        stack += [(c, depth + 1) for c in children]


def _no_alias(loader, parent, index):
    if loader.check_event(yaml.AliasEvent):
        ev = loader.peek_event()
        raise yaml.YAMLError(f"YAML aliases (*{str(ev.anchor)[:40]}) are not allowed in configs, line "
                             f"{ev.start_mark.line + 1}")
    depth = getattr(loader, "_depth", 0)
    if depth >= MAX_CONFIG_DEPTH:
        raise yaml.YAMLError(f"nested more than {MAX_CONFIG_DEPTH} levels deep (line "
                             f"{loader.peek_event().start_mark.line + 1}); a config is a few levels deep")
    loader._depth = depth + 1
    try:
        return yaml.SafeLoader.compose_node(loader, parent, index)
    finally:
        loader._depth = depth


_Loader.compose_node = _no_alias  # an alias bomb cannot expand: aliases are refused while composing


def _short(exc: Exception, limit: int = 300) -> str:
    """An exception's message cut to a few lines (a config error never floods the terminal)."""
    text = " ".join(str(exc).split())
    return text if len(text) <= limit else text[:limit] + " ..."


def load_yaml_text(text: str) -> Any:
    """Parse YAML text with the project's loader (safe, scientific floats, no aliases)."""
    return yaml.load(text, Loader=_Loader)


def override_key(item: str) -> str:
    """The dotted key of a ``key=value`` override, as `parse_overrides` reads it (before the first '=')."""
    return item.split("=", 1)[0].strip()


def parse_overrides(overrides: Iterable[str]) -> dict[str, Any]:
    """Parse ``a.b=value`` strings into a nested dict; values are parsed as YAML scalars/lists."""
    out: dict[str, Any] = {}
    items = list(overrides)
    if len(items) > MAX_CONFIG_KEYS:
        raise ConfigError(f"{len(items)} overrides, more than the {MAX_CONFIG_KEYS} keys a config may have")
    for item in items:
        if "=" not in item:
            raise ConfigError(f"override {_cut(item)!r} is not of the form key=value (e.g. rig.overlap=0.3)")
        key, raw = override_key(item), item.split("=", 1)[1]
        if not key or any(not part for part in key.split(".")):
            raise ConfigError(f"override {_cut(item)!r} has an empty key")
        parts = key.split(".")
        if len(parts) > MAX_CONFIG_DEPTH:
            raise ConfigError(f"override {_cut(key)}: nested more than {MAX_CONFIG_DEPTH} levels deep ({len(parts)} "
                              "dotted parts); a config is a few levels deep")
        try:
            value = load_yaml_text(raw) if raw.strip() != "" else ""
        except yaml.YAMLError as exc:
            raise ConfigError(f"override {_cut(key)}: cannot parse value {raw[:80]!r}: {_short(exc)}") from None
        node = out
        for p in parts[:-1]:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ConfigError(f"override {_cut(key)}: {_cut(p)} is set both as a value and as a section")
        node[parts[-1]] = value
    check_bounds(out, "overrides")
    return out


def deep_merge(base: dict[str, Any], upd: dict[str, Any]) -> dict[str, Any]:
    """Recursively merge `upd` into a copy of `base` (dicts merge, everything else replaces)."""
    res = dict(base)
    for k, v in upd.items():
        if isinstance(v, dict) and isinstance(res.get(k), dict):
            res[k] = deep_merge(res[k], v)
        else:
            res[k] = v
    return res


def read_yaml(path: str | Path) -> dict[str, Any]:
    """Read a YAML mapping; errors name the file."""
    p = Path(path)
    name = _cut(str(p), 300)
    try:
        if not p.is_file():
            raise ConfigError(f"config file {name} does not exist")
    except OSError as exc:  # a name longer than the file system allows
        raise ConfigError(f"config file {name}: {exc.strerror or exc}") from None
    size = p.stat().st_size
    if size > MAX_CONFIG_BYTES:
        raise ConfigError(f"config file {name} is {size} bytes, more than the {MAX_CONFIG_BYTES} a config may have")
    try:
        data = load_yaml_text(read_text_file(p, kind="config", link_ok=True))  # the one rule (corelib.readfile)
    except ReadRefused as exc:
        raise ConfigError(f"config file {name}: {_short(exc)}") from None
    except (yaml.YAMLError, UnicodeDecodeError) as exc:
        raise ConfigError(f"config file {name} is not valid YAML: {_short(exc)}") from None
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"config file {name} must hold a mapping at the top level, not {type(data).__name__}")
    check_bounds(data, f"config file {name}")
    return data


def build_config(cls: Type[T], data: dict[str, Any], source: str = "config") -> T:
    """Validate a plain dict into `cls`, turning pydantic errors into `ConfigError`."""
    try:
        return cls.model_validate(data)
    except ValidationError as err:
        raise ConfigError(_format_validation_error(err, source)) from None


def nest(values: dict[str, Any]) -> dict[str, Any]:
    """``{"a.b": 1, "c": 2}`` -> ``{"a": {"b": 1}, "c": 2}`` (values as given, not parsed)."""
    out: dict[str, Any] = {}
    for key, value in values.items():
        node = out
        parts = key.split(".")
        for p in parts[:-1]:
            node = node.setdefault(p, {})
        node[parts[-1]] = value
    return out


def resolve_path(p: str | Path, kind: str) -> Path:
    """A preset path as the user typed it: relative to the working directory if it exists there, else
    to the project root (``configs/...`` works from anywhere); ConfigError naming ``kind`` otherwise."""
    p = Path(p)
    try:
        if p.is_absolute() or p.exists():
            return p
        alt = PROJECT_ROOT / p
        if alt.exists():
            return alt
    except OSError as exc:  # a name longer than the file system allows
        raise ConfigError(f"{kind} {_cut(str(p), 300)}: {exc.strerror or exc}") from None
    raise ConfigError(f"{kind} {_cut(str(p), 300)} does not exist (looked in {Path.cwd()} and {PROJECT_ROOT})")


def load_config(cls: Type[T], path: str | Path | None = None, overrides: Iterable[str] = (),
                values: dict[str, Any] | None = None, base: dict[str, Any] | None = None) -> T:
    """Load a preset file (optional) over ``base`` (dotted keys -> values: defaults the preset may
    change), apply a user's ``key=value`` overrides, then the program's own ``values`` (dotted keys ->
    Python values, no text round trip); returns a frozen config. A relative ``path`` that is not in the
    working directory is looked up under the project root (`resolve_path`: ``configs/...`` from anywhere)."""
    if path is not None:
        path = resolve_path(path, "config file")
    data = deep_merge(nest(base or {}), read_yaml(path) if path is not None else {})
    ov = list(overrides)
    data = deep_merge(data, parse_overrides(ov))
    if values:
        data = deep_merge(data, nest(values))
    source = str(path) if path is not None else "defaults"
    if ov:
        source += " + overrides " + " ".join(ov)
    if values:
        source += " + " + ", ".join(sorted(values))
    check_bounds(data, f"config {source}")
    return build_config(cls, data, source)


def config_to_dict(cfg: BaseModel) -> dict[str, Any]:
    """Plain JSON-able dict of a config (the resolved config saved with every output)."""
    return cfg.model_dump(mode="json")


#: the mark of a key added after the artefacts it configures were first cached (`added_key`)
_ADDED = "hashed_only_when_set"


def added_key(default: Any = ..., **kw) -> Any:
    """A pydantic Field for a key added to a config that caches hang on (datasets, runs): the key enters
    `config_hash` only when its value differs from ``default``, so adding it with a default that leaves
    the artefact as it was keeps every existing hash, and with it every cached render and run."""
    extra = dict(kw.pop("json_schema_extra", None) or {})
    extra[_ADDED] = True
    if "default_factory" in kw:
        return Field(json_schema_extra=extra, **kw)
    return Field(default, json_schema_extra=extra, **kw)


def _hashed(cfg: BaseModel, d: dict[str, Any]) -> dict[str, Any]:
    """`d` (= config_to_dict(cfg)) without the `added_key` keys that hold their default, at every depth (in
    sections and in mappings of sections)."""
    out = dict(d)
    for name, field in type(cfg).model_fields.items():
        value = getattr(cfg, name)
        extra = field.json_schema_extra if isinstance(field.json_schema_extra, dict) else {}
        if extra.get(_ADDED) and value == field.get_default(call_default_factory=True):
            out.pop(name, None)
        elif isinstance(value, BaseModel) and isinstance(out.get(name), dict):
            out[name] = _hashed(value, out[name])
        elif isinstance(value, dict) and isinstance(out.get(name), dict):  # a mapping of sections (rig.cameras)
            sub = out[name]
            out[name] = {k: _hashed(v, sub[k]) if isinstance(v, BaseModel) and isinstance(sub.get(k), dict) else sub[k]
                         for k, v in value.items()}
    return cfg.hashed_form(out) if isinstance(cfg, StrictModel) else out


def hashed_dict(cfg: BaseModel) -> dict[str, Any]:
    """What `config_hash` hashes of a config: its plain dict without the `added_key` keys at their default
    (use it to build a hash of several configs together)."""
    return _hashed(cfg, config_to_dict(cfg))


def config_hash(cfg: BaseModel | dict[str, Any]) -> str:
    """sha256 of the canonical JSON of a config: same resolved config, same hash. Keys declared with
    `added_key` count only when set to something other than their default."""
    d = _hashed(cfg, config_to_dict(cfg)) if isinstance(cfg, BaseModel) else cfg
    return json_sha256(d)


def diff_configs(a: dict[str, Any], b: dict[str, Any], prefix: str = "") -> list[str]:
    """Dotted keys whose values differ between two plain config dicts."""
    keys = sorted(set(a) | set(b))
    out: list[str] = []
    for k in keys:
        path = f"{prefix}{k}"
        va, vb = a.get(k), b.get(k)
        if isinstance(va, dict) and isinstance(vb, dict):
            out.extend(diff_configs(va, vb, path + "."))
        elif va != vb:
            out.append(path)
    return out
