"""Parameters checked where they are defined: one reading of the fields' metadata for every stage.

Every field of a params dataclass declares what it is::

    t_d: float = field(default=0.30, metadata={"help": "one line", "unit": "", "range": (0.01, 2.0)})

(``range`` inclusive, None for an open end; ``unit`` "" for fractions and counts). `check_fields`,
called by each class's ``__post_init__``, converts and checks every field against its type (from
the annotation, else the default's type) and range: numbers must be finite, integers whole, bools
bools. A field without metadata gets the type check only. `coerce` is the one conversion of a
value given by name (a CLI ``--param`` string, a sweep file's YAML value), with `parse_bool` the
one reading of a bool. `param_help` prints the parameters of stages from the same metadata.
"""

from __future__ import annotations

import dataclasses
import math
import numbers

#: The one spelling of bools (case-insensitive).
TRUE, FALSE = ("true", "1", "yes", "on"), ("false", "0", "no", "off")

#: Annotations (``from __future__ import annotations`` makes them strings) understood here.
_SIMPLE = {"float": float, "int": int, "bool": bool, "str": str, "tuple": tuple}


def parse_bool(value, name: str = "value", error=ValueError) -> bool:
    """``value`` as a bool: True/False, 0/1, or one of true/false/1/0/yes/no/on/off (any case)."""
    if isinstance(value, bool):
        return value
    if isinstance(value, numbers.Integral) and int(value) in (0, 1):
        return bool(value)
    if isinstance(value, str):
        text = value.strip().lower()
        if text in TRUE:
            return True
        if text in FALSE:
            return False
    raise error(f"parameter {name}={value!r}: expected a bool (true/false, 1/0, yes/no, on/off)")


def kind(f: dataclasses.Field):
    """The Python type of field ``f`` (float, int, bool, str, tuple), or None for other types."""
    t = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", "")
    if t in _SIMPLE:
        return _SIMPLE[t]
    default = _default(f)
    for typ in (bool, int, float, str, tuple):
        if isinstance(default, typ):
            return typ
    return None


def _numeric_tuple(f: dataclasses.Field) -> bool:
    """Whether field ``f`` holds a tuple of numbers (its default's items are numbers)."""
    default = _default(f)
    return (isinstance(default, tuple) and bool(default)
            and all(isinstance(x, numbers.Real) and not isinstance(x, bool) for x in default))


def _default(f: dataclasses.Field):
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        try:
            return f.default_factory()
        except Exception:
            return None
    return None


def _number(value, name, typ, error):
    if isinstance(value, str):
        text = value.strip()
        try:
            value = float(text) if typ is float or not text.lstrip("+-").isdigit() else int(text)
        except ValueError:
            raise error(f"parameter {name}={text!r}: expected {'a number' if typ is float else 'an integer'}") \
                from None
    if isinstance(value, bool) or not isinstance(value, numbers.Real):
        raise error(f"parameter {name}={value!r}: expected {'a number' if typ is float else 'an integer'}")
    if not math.isfinite(float(value)):
        raise error(f"parameter {name}={value!r}: must be a finite number")
    if typ is int:
        if isinstance(value, numbers.Integral):
            return int(value)
        if float(value).is_integer():
            return int(value)
        raise error(f"parameter {name}={value!r}: expected an integer")
    return float(value)


def coerce(f: dataclasses.Field, value, error=ValueError, name: str | None = None):
    """``value`` (typed, or a string from the command line) converted to field ``f``'s type and
    checked against its range; raise ``error`` with one line naming the parameter otherwise."""
    name = name or f.name
    typ = kind(f)
    if typ is bool:
        value = parse_bool(value, name, error)
    elif typ in (int, float):
        value = _number(value, name, typ, error)
    elif typ is str:
        if not isinstance(value, str):
            raise error(f"parameter {name}={value!r}: expected a string")
    elif typ is tuple and _numeric_tuple(f):
        if isinstance(value, str):
            value = [x for x in value.replace(",", " ").split() if x]
        if not isinstance(value, (list, tuple)) or not value:
            raise error(f"parameter {name}={value!r}: expected a non-empty list of numbers (a,b,c)")
        value = tuple(_number(x, name, float, error) for x in value)
    rng = f.metadata.get("range") if f.metadata else None
    if rng is not None and (typ in (int, float) or (typ is tuple and _numeric_tuple(f))):
        lo, hi = rng
        for x in (value if typ is tuple else (value,)):
            if (lo is not None and x < lo) or (hi is not None and x > hi):
                unit, what = f.metadata.get("unit") or "", f.metadata.get("help")
                raise error(f"parameter {name}={x!r}: must be in {_range_text(rng)}"
                            + (f" {unit}" if unit else "") + (f" ({what})" if what else ""))
    return value


def check_fields(obj, error=ValueError) -> None:
    """Convert and check every field of the dataclass instance ``obj`` in place (frozen or not)."""
    for f in dataclasses.fields(obj):
        value = getattr(obj, f.name)
        if kind(f) is None or (kind(f) is tuple and not _numeric_tuple(f)):
            continue
        checked = coerce(f, value, error)
        if checked is not value:
            object.__setattr__(obj, f.name, checked)


def field_named(cls, name: str):
    """The field ``name`` of dataclass ``cls``, or None."""
    return next((f for f in dataclasses.fields(cls) if f.name == name), None)


def _range_text(rng) -> str:
    lo, hi = rng
    return f"[{'-inf' if lo is None else f'{lo:g}'}, {'inf' if hi is None else f'{hi:g}'}]"


def _value_text(value) -> str:
    if isinstance(value, tuple):
        return ",".join(f"{v:g}" if isinstance(v, float) else str(v) for v in value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def describe(cls, instance=None) -> list[str]:
    """One line per field of ``cls``: name, default, unit, range and meaning."""
    instance = instance if instance is not None else cls()
    rows = []
    for f in dataclasses.fields(cls):
        if kind(f) is None and not f.metadata:
            continue
        meta = f.metadata or {}
        value = getattr(instance, f.name)
        typ = kind(f)
        what = meta.get("unit") or ""
        if meta.get("range") is not None:
            what = (what + " " if what else "") + _range_text(meta["range"])
        elif typ is bool:
            what = "true/false"
        shown = _value_text(value) if typ and (typ is not tuple or _numeric_tuple(f)) else "..."
        rows.append((f"{f.name}={shown}", what,
                     meta.get("help", "(no description)")))
    width = min(36, max((len(a) for a, _, _ in rows), default=0))
    wunit = min(24, max((len(b) for _, b, _ in rows), default=0))
    return [f"  {a:<{width}}  {b:<{wunit}}  {c}" for a, b, c in rows]


def param_help(stages: dict) -> str:
    """Text listing the parameters of ``{stage title: dataclass (or instance)}``, grouped by stage."""
    out = ["Parameters (NAME=default, unit and inclusive range, meaning); set with --param NAME=VALUE. "
           "Units: m metres, deg degrees, rad radians; 'spacings' are median point spacings, 'widths' "
           "section widths; no unit: a count, fraction or factor."]
    for title, cls in stages.items():
        instance = None
        if not isinstance(cls, type):
            cls, instance = type(cls), cls
        out += ["", f"{title}:"] + describe(cls, instance)
    return "\n".join(out)


def wants_help(items) -> bool:
    """Whether ``--param`` items ask for the parameter list (``--param help``)."""
    return any(str(item).strip().lower() in ("help", "list", "?") for item in items or ())


def param_action(listing):
    """An argparse action for a repeatable ``--param NAME=VALUE``: ``--param help`` prints
    ``listing()`` (the parameter list, built only then) and exits, as ``--help`` does, before the
    command's other arguments are checked (``bodyscan fit --param help`` needs no cloud)."""
    import argparse

    class ParamAction(argparse.Action):
        def __call__(self, parser, namespace, values, option_string=None):
            if wants_help([values]):
                print(listing())
                parser.exit()
            setattr(namespace, self.dest, list(getattr(namespace, self.dest, None) or []) + [values])

    return ParamAction


def fields_without_help(cls) -> list[str]:
    """Names of the fields of ``cls`` that lack a one-line ``help`` in their metadata."""
    return [f.name for f in dataclasses.fields(cls) if not (f.metadata or {}).get("help")]
