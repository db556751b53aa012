"""params.yaml machinery: frozen dataclasses per section, unknown keys rejected.

Each section's dataclass lives beside the code that uses it (``SensorConfig`` in
:mod:`rdnet.sim.settings`, ...); :data:`SECTIONS` maps section names to them. Use::

    params = load_params("params.yaml", sets=["degrade.refractory_us=500"])
    degrade = section(params, "degrade")          # -> DegradeConfig, validated

Overrides take the dotted keys of params.yaml (``section.key=value``, values parsed as
YAML); a key that does not exist in the file is an error, as in ``dvc exp run -S``.
"""
from __future__ import annotations

import copy
import re
import dataclasses
import importlib
import types
import typing
from pathlib import Path
from typing import Any, Iterable, Mapping

import yaml

from rdnet.errors import ConfigError

#: section name -> "module:Class" of its frozen dataclass (imported lazily).
SECTIONS: dict[str, str] = {
    "scenes": "rdnet.sim.scenes:ScenesConfig",
    "interpolate": "rdnet.sim.interpolate:InterpolateConfig",
    "sensor": "rdnet.sim.settings:SensorConfig",
    "degrade": "rdnet.sim.settings:DegradeConfig",
    "randomize": "rdnet.sim.settings:RandomizeConfig",
    "blur": "rdnet.sim.blur:BlurConfig",
    "voxel": "rdnet.events.voxel_config:VoxelConfig",
    "model": "rdnet.train.config:ModelConfig",
    "train": "rdnet.train.config:TrainConfig",
    "ablation": "rdnet.study.rows:AblationConfig",
    "study": "rdnet.study.config:StudyConfig",
    "calibrate": "rdnet.calib.settings:CalibrateConfig",
    "deblur": "rdnet.deblur.config:DeblurConfig",
    "restore": "rdnet.restore.settings:RestoreConfig",
    "ednccn": "rdnet.restore.settings:EdnccnConfig",
}


def register_section(name: str, target: str) -> None:
    SECTIONS[name] = target


def section_class(name: str) -> type:
    try:
        target = SECTIONS[name]
    except KeyError:
        raise ConfigError(name, f"unknown section; known: {', '.join(sorted(SECTIONS))}")
    mod, _, cls = target.partition(":")
    return getattr(importlib.import_module(mod), cls)


def _coerce(value: Any, tp: Any, key: str) -> Any:
    origin = typing.get_origin(tp)
    args = typing.get_args(tp)
    if tp is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return None
        errs = []
        for a in args:
            if a is type(None):
                continue
            try:
                return _coerce(value, a, key)
            except ConfigError as e:
                errs.append(str(e))
        raise ConfigError(key, f"value {value!r} does not fit {tp}")
    if origin is typing.Literal:
        if value not in args:
            raise ConfigError(key, f"must be one of {list(args)}, got {value!r}")
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(key, f"expected a list, got {value!r}")
        if origin is tuple and len(args) == 2 and args[1] is Ellipsis:
            return tuple(_coerce(v, args[0], key) for v in value)
        if origin is tuple and args:
            if len(args) != len(value):
                raise ConfigError(key, f"expected {len(args)} values, got {len(value)}")
            return tuple(_coerce(v, a, key) for v, a in zip(value, args))
        return tuple(value) if origin is tuple else list(value)
    if origin is dict or tp is dict:
        if not isinstance(value, Mapping):
            raise ConfigError(key, f"expected a mapping, got {value!r}")
        return dict(value)
    if dataclasses.is_dataclass(tp):
        if isinstance(value, tp):
            return value
        return from_dict(tp, value, key)
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(key, f"expected true/false, got {value!r}")
        return value
    if tp is int:
        if isinstance(value, bool) or not (isinstance(value, int) or (isinstance(value, float) and value.is_integer())):
            raise ConfigError(key, f"expected an integer, got {value!r}")
        return int(value)
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(key, f"expected a number, got {value!r}")
        return float(value)
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(key, f"expected a string, got {value!r}")
        return value
    return value


def from_dict(cls: type, data: Mapping | None, section: str, source: str | Path | None = None):
    """Build frozen dataclass ``cls`` from ``data``; unknown keys and bad types raise
    :class:`ConfigError` naming ``section.key``. Missing keys take the defaults."""
    data = {} if data is None else data
    if not isinstance(data, Mapping):
        raise ConfigError(section, f"expected a mapping, got {type(data).__name__}", source)
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(data) - set(fields))
    if unknown:
        raise ConfigError(f"{section}.{unknown[0]}", f"unknown key; known keys: {', '.join(fields)}", source)
    try:
        kwargs = {name: _coerce(value, hints[name], f"{section}.{name}") for name, value in data.items()}
        return cls(**kwargs)
    except ConfigError as e:
        if source and not e.source:
            raise ConfigError(e.key, e.detail, source) from None
        raise
    except TypeError as e:
        raise ConfigError(section, str(e), source) from None


def to_dict(obj) -> dict:
    """Plain-dict form of a config dataclass (tuples become lists, for YAML/JSON)."""
    def conv(v):
        if dataclasses.is_dataclass(v):
            return {f.name: conv(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [conv(x) for x in v]
        if isinstance(v, dict):
            return {k: conv(x) for k, x in v.items()}
        return v
    return conv(obj)


def read_yaml(path: str | Path) -> dict:
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8")
    except OSError as e:
        raise ConfigError("params", f"cannot read: {e.strerror}", path) from None
    except UnicodeDecodeError as e:
        raise ConfigError("params", f"not a YAML text file (byte {e.start} is not UTF-8)", path) from None
    try:
        data = yaml.safe_load(text) or {}
    except yaml.YAMLError as e:
        raise ConfigError("params", f"invalid YAML: {_yaml_problem(e)}", path) from None
    if not isinstance(data, dict):
        raise ConfigError("params", "top level must be a mapping", path)
    return data


def read_json(path: str | Path):
    """The JSON document in ``path``; :class:`~rdnet.errors.FormatError` naming the file when
    it cannot be read or parsed (a metrics file or report another stage wrote)."""
    import json

    from rdnet.errors import FormatError
    try:
        return json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise FormatError(path, None, "no such file (run the stage that writes it first)") from None
    except (OSError, ValueError) as e:
        raise FormatError(path, None, f"not readable JSON: {e}") from None


def _yaml_problem(e: "yaml.YAMLError") -> str:
    """One line for a YAML error: the problem and where (PyYAML's own message spans lines)."""
    mark = getattr(e, "problem_mark", None)
    problem = getattr(e, "problem", None) or str(e).splitlines()[0]
    return f"{problem} (line {mark.line + 1}, column {mark.column + 1})" if mark is not None else problem


#: a number in exponent form that YAML 1.1 (PyYAML) leaves a string (no dot, or no sign in
#: the exponent: 1e3, 2.5e3)
_EXPONENT_NUMBER = re.compile(r"[-+]?(\d+\.?\d*|\.\d+)[eE][-+]?\d+")


def parse_set(item: str) -> tuple[list[str], Any]:
    """``"a.b=3"`` -> (["a", "b"], 3). The value is parsed as YAML."""
    if "=" not in item:
        raise ConfigError(item, "expected section.key=value")
    key, _, raw = item.partition("=")
    key = key.strip()
    if not key or any(not part for part in key.split(".")):
        raise ConfigError(item, "expected section.key=value")
    try:
        value = yaml.safe_load(raw) if raw.strip() else ""
    except yaml.YAMLError:
        value = raw
    except ValueError as e:            # e.g. an integer of more digits than Python converts
        raise ConfigError(key, f"cannot read the value ({str(e).splitlines()[0][:120]})") from None
    return key.split("."), _exponent_numbers(value)


def _exponent_numbers(value):
    """``value`` with every string in exponent form read as a float, inside lists and
    mappings too (YAML 1.1 reads 1e3, without a dot, as a string: ``[1.0, 1e300]``)."""
    if isinstance(value, str) and _EXPONENT_NUMBER.fullmatch(value.strip()):
        return float(value)
    if isinstance(value, list):
        return [_exponent_numbers(v) for v in value]
    if isinstance(value, dict):
        return {k: _exponent_numbers(v) for k, v in value.items()}
    return value


def _nested_section(cls, name: str):
    """The dataclass type of field ``name`` of dataclass ``cls`` when that field holds a
    nested dataclass (``ablation.filters``), else None."""
    if cls is None or not dataclasses.is_dataclass(cls):
        return None
    for f in dataclasses.fields(cls):
        if f.name == name:
            default = f.default if f.default is not dataclasses.MISSING else (
                f.default_factory() if f.default_factory is not dataclasses.MISSING else None)
            return type(default) if dataclasses.is_dataclass(default) else None
    return None


def apply_sets(params: Mapping, sets: Iterable[str], source: str | Path | None = None) -> dict:
    """A copy of ``params`` with dotted overrides applied. The key must exist already
    (except inside free-form mappings of a dataclass field typed ``dict``)."""
    out = copy.deepcopy(dict(params))
    for item in sets or ():
        parts, value = parse_set(item)
        if len(parts) == 1 and not isinstance(value, dict):   # restore=null would reset a whole section
            raise ConfigError(parts[0], f"a whole section takes a mapping of keys, got {value!r}; "
                                        f"set one key with {parts[0]}.KEY=VALUE", source)
        node = out
        cls = section_class(parts[0]) if parts[0] in SECTIONS else None   # the dataclass of `node`
        for i, part in enumerate(parts[:-1]):
            if i > 0:
                nested = _nested_section(cls, part)
                if isinstance(node, dict) and part not in node and nested is not None:
                    node[part] = {}        # a nested section the file omits (ablation.filters)
                cls = nested
            if not isinstance(node, dict) or part not in node:
                raise ConfigError(".".join(parts), "unknown key (not in params)", source)
            node = node[part]
        last = parts[-1]
        if not isinstance(node, dict) or last not in node:
            # allow sections known to rdnet even if the file omits the key
            if cls is not None and isinstance(node, dict):
                if last not in {f.name for f in dataclasses.fields(cls)}:
                    raise ConfigError(".".join(parts), "unknown key", source)
            else:
                raise ConfigError(".".join(parts), "unknown key (not in params)", source)
        node[last] = value
    return out


def load_params(path: str | Path | None = None, sets: Iterable[str] = (), *,
                base: Mapping | None = None) -> dict:
    """Read params.yaml (or start from ``base``), apply overrides, validate every known
    section, and return the plain dict."""
    if path is not None:
        params = read_yaml(path)
    else:
        params = copy.deepcopy(dict(base or {}))
    for name in SECTIONS:
        params.setdefault(name, {})
    params = apply_sets(params, sets, path)
    given = {".".join(parse_set(item)[0]): item for item in sets or ()}
    for name in SECTIONS:
        try:
            from_dict(section_class(name), params.get(name), name, path)
        except ConfigError as e:
            if e.key in given:         # the bad value came from --set, not from the file
                raise ConfigError(e.key, e.detail, f"--set {given[e.key]}") from None
            raise
    return params


def section(params: Mapping, name: str, source: str | Path | None = None):
    """The validated frozen dataclass of section ``name``."""
    return from_dict(section_class(name), params.get(name) or {}, name, source)


def positive(key: str, value: float, *, allow_zero: bool = True) -> None:
    """Range check helper for ``__post_init__``: a finite number ``>= 0`` (``> 0`` without
    ``allow_zero``). Infinity is refused too: no setting means "unbounded" by it, and an
    infinite threshold, rate or epsilon only gave empty or NaN results."""
    if value != value or value < 0 or (not allow_zero and value == 0):
        raise ConfigError(key, f"must be {'>= 0' if allow_zero else '> 0'}, got {value}")
    if value == float("inf"):
        raise ConfigError(key, "must be finite, got inf")


#: one hour in microseconds: the bound of the settings that are durations in int64
#: microseconds (far beyond any sensor's; larger values overflowed the timestamp arithmetic)
ONE_HOUR_US = 3.6e9


#: the bound of event rates in Hz: a pixel cannot fire faster than about 1 MHz (its reset and
#: readout take about a microsecond), and the timestamps count whole microseconds
MAX_RATE_HZ = 1e6

#: the bound of thread and process counts: more than the cores of any machine (100000
#: threads exhausted the memory before the work began)
MAX_THREADS = 256

#: the bound of seeds: 32 bits, which every generator the code seeds takes (numpy's take any
#: size; ``torch.manual_seed`` gave a traceback beyond 2^64)
MAX_SEED = 2 ** 32 - 1


def at_most(key: str, value: float, most: float) -> None:
    """Range check helper for ``__post_init__``: ``value`` <= ``most`` (durations:
    :data:`ONE_HOUR_US`, named as an hour in the message)."""
    if value > most:
        unit = " us (an hour)" if most == ONE_HOUR_US else ""
        raise ConfigError(key, f"must be at most {most:g}{unit}, got {value:g}")


def at_least(key: str, value: float, least: float) -> None:
    """Range check helper for ``__post_init__``: ``value`` >= ``least`` (a lower bound above 0,
    for keys where a tiny value is not "off" but runs without end)."""
    if value < least:
        raise ConfigError(key, f"must be at least {least:g}, got {value:g}")


def check_bounds(section: str, cfg, upper: Mapping[str, float], lower: Mapping[str, float] | None = None) -> None:
    """Range check helper for ``__post_init__``: each key of ``upper`` of ``cfg`` is at most its
    bound (:func:`at_most`), each key of ``lower`` at least its bound (:func:`at_least`); the
    message names ``section.key``. An unset optional key (None) is skipped, and every number
    of a list or tuple is checked (nested ranges too)."""
    for bounds, check in ((upper, at_most), (lower or {}, at_least)):
        for key, bound in bounds.items():
            for value in _numbers(getattr(cfg, key)):
                check(f"{section}.{key}", value, bound)


def _numbers(value) -> Iterable:
    if isinstance(value, (list, tuple)):
        for v in value:
            yield from _numbers(v)
    elif value is not None:
        yield value


# --- command-line access (``--params`` / ``--set``), shared by the CLI and entry points --

#: What :func:`params_source` reports when no params.yaml is read.
BUILTIN_DEFAULTS = "built-in defaults"


def add_params_args(p) -> None:
    """Add ``--params`` and ``--set`` to an argparse parser (read by :func:`load_cli_params`)."""
    p.add_argument("--params", type=Path, default=None,
                   help="params.yaml to read (default: ./params.yaml if present, else built-in defaults)")
    p.add_argument("--set", dest="sets", action="append", default=[], metavar="SECTION.KEY=VALUE",
                   help="override a params.yaml key (repeatable), e.g. degrade.refractory_us=500")


def seed_arg(text: str) -> int:
    """argparse ``type`` of a ``--seed``: a whole number >= 0 (numpy's generators take no
    negative seed)."""
    import argparse
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a whole number >= 0, got {text!r}") from None
    if value < 0:
        raise argparse.ArgumentTypeError(f"must be >= 0, got {value}")
    return value


def cli_params_path(args) -> Path | None:
    """The params.yaml a command reads: ``--params``, else ./params.yaml when present, else
    None (built-in defaults)."""
    if args.params is not None:
        return args.params
    return Path("params.yaml") if Path("params.yaml").is_file() else None


def params_source(args) -> str:
    """Where a command's params come from, for logs and output attributes: the absolute
    path of the params.yaml read, or :data:`BUILTIN_DEFAULTS`."""
    path = cli_params_path(args)
    return BUILTIN_DEFAULTS if path is None else str(Path(path).resolve())


def load_cli_params(args) -> dict:
    """Params of a command: :func:`cli_params_path` with the ``--set`` overrides applied."""
    return load_params(cli_params_path(args), args.sets)
