"""The methods the benchmark runs: the built-in ones and your own.

A method is named by a *spec*, a string that every command and every worker process resolves
the same way:

- a built-in name: ``proposed`` and ``simple`` (`recon`), ``poisson``, ``poisson-trimmed``,
  ``bpa``, ``alpha``, ``spsr`` (`benchmarks.peers`);
- the name of an installed entry point in the group ``bodyscan.methods`` (a package of yours
  declaring ``[project.entry-points."bodyscan.methods"] mymethod = "mypkg.mod:reconstruct"``);
- ``module.path:function``: a Python callable, importable where the benchmark runs (installed,
  on ``PYTHONPATH``, or in the current directory);
- ``cmd:TEMPLATE``: an external command (``bodyscan bench --method-cmd TEMPLATE``).

Any of the last two may start with ``NAME=`` to give it the name shown in the tables
(``tiny=mymod:reconstruct``); otherwise a callable is named by its spec and a command by its
program (``cmd:mytool {cloud} {out}`` is ``mytool``).

**The callable's contract**::

    def reconstruct(points, view_dir, head, *, radius=0.02, ...):
        return vertices, faces            # or (vertices, faces, extra)

- ``points`` : (n, 3) float64, metres (+z up, the subject faces -y);
- ``view_dir`` : (n, 3) float64, unit vector from each point toward the camera that saw it;
- ``head`` : (n,) int64, the scanner head (camera and laser) that measured each point;
- keyword arguments with defaults are the method's own parameters: ``--param radius=0.03`` in
  ``bench``, ``method_params: {NAME: {radius: [0.01, 0.03]}}`` axes in a sweep file;
- ``vertices`` : (V, 3) float, metres; ``faces`` : (F, 3) int, counter-clockwise seen from
  outside;
- ``extra`` (optional dict, every key optional): ``point_index`` (V,) int, the input point each
  vertex is (-1 for none; default: matched by position within 1 micrometre);
  ``point_sections`` (n, 11) bool, section labels of the points (gives section accuracy);
  ``joints`` {name: (3,)} (gives the joint error); ``face_section`` (F,) int (pictures);
  ``times`` {stage: seconds}.

**The command's contract**: ``{cloud}`` is replaced by a binary PLY of the points (``x y z``
double, ``vx vy vz`` float view directions, ``head`` short; never any ground truth), ``{out}`` by
the path of the mesh to write (PLY; any mesh format trimesh reads), ``{NAME}`` by the value of
the method's parameter NAME (every other placeholder is a parameter, given with ``--param`` or
``method_params``). The template is split like a shell command line (no shell runs it). A
non-zero exit status, or no mesh written, is a failure of that case with the command's last
error line.
"""

from __future__ import annotations

import inspect
import re
import shlex
import string
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from . import BenchError

#: Entry point group of installed methods.
ENTRY_POINT_GROUP = "bodyscan.methods"
#: Seconds an external command may run.
COMMAND_TIMEOUT_S = 600

_NAMED = re.compile(r"^([A-Za-z_][\w.+-]*)=(.+)$", re.S)
_CALLABLE = re.compile(r"^[A-Za-z_][\w.]*:[A-Za-z_]\w*$")


class MethodError(BenchError):
    """A method that cannot be resolved, or that failed to produce a mesh."""


@dataclass(frozen=True)
class Method:
    """A resolved method.

    Attributes
    ----------
    name : str
        The name in the tables (the ``method`` column).
    spec : str
        What resolves to it again (in a worker process).
    kind : str
        ``recon`` (proposed, simple), ``peer``, ``python`` or ``command``.
    target : str
        ``module:function`` of a python method, the template of a command.
    """

    name: str
    spec: str
    kind: str
    target: str = ""

    @property
    def builtin(self) -> bool:
        return self.kind in ("recon", "peer")

    def function(self):
        """The python method's callable, imported from the environment or, failing that, from
        the current directory (as ``python -m`` would)."""
        import importlib
        import os
        import sys

        if os.getcwd() not in sys.path:
            sys.path.append(os.getcwd())
        module, _, attr = self.target.partition(":")
        try:
            fn = getattr(importlib.import_module(module), attr)
        except (ImportError, AttributeError) as exc:
            raise MethodError(f"method {self.name}: cannot import {self.target} ({exc})") from None
        if not callable(fn):
            raise MethodError(f"method {self.name}: {self.target} is not callable")
        return fn

    def defaults(self) -> dict:
        """The method's own parameters and their defaults (None: no default, must be given)."""
        if self.kind == "python":
            sig = inspect.signature(self.function())
            params = list(sig.parameters.values())
            return {p.name: (None if p.default is p.empty else p.default) for p in params[3:]
                    if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        if self.kind == "command":
            names = [f for _, f, _, _ in string.Formatter().parse(self.target) if f]
            return {n: None for n in dict.fromkeys(names) if n not in ("cloud", "out")}
        return {}

    def check_params(self, params: dict | None) -> dict:
        """``params`` with defaults filled in and text converted to the defaults' types.

        Raises
        ------
        MethodError
            An unknown parameter, a missing one, or a value of the wrong type.
        """
        defaults = self.defaults()
        params = dict(params or {})
        unknown = sorted(set(params) - set(defaults))
        if unknown:
            known = ", ".join(defaults) or "none"
            raise MethodError(f"method {self.name}: unknown parameter(s) {', '.join(unknown)} "
                              f"(its parameters: {known})")
        out = {}
        for name, default in defaults.items():
            value = params.get(name, default)
            if value is None:
                raise MethodError(f"method {self.name}: parameter {name} has no default; give it "
                                  f"(--param {name}=VALUE, or method_params in a sweep file)")
            if isinstance(value, str) and default is not None and not isinstance(default, str):
                value = _convert(self.name, name, value, default)
            elif isinstance(value, str) and default is None:   # a command's: a number if it reads as one
                value = _number(value)
            out[name] = value
        return out

    def run(self, points, view_dir, head, params: dict | None = None):
        """Reconstruct: ``(vertices (V, 3) float64, faces (F, 3) int64, extra dict, times dict)``
        for a python or command method (see the module docstring)."""
        params = self.check_params(params)
        p = np.ascontiguousarray(points, dtype=np.float64)
        vd = np.ascontiguousarray(np.broadcast_to(view_dir, p.shape), dtype=np.float64)
        hd = np.zeros(len(p), np.int64) if head is None else np.asarray(head, dtype=np.int64)
        t0 = time.perf_counter()
        if self.kind == "python":
            result = self.function()(p, vd, hd, **params)
            extra = {}
            if isinstance(result, tuple) and len(result) == 3:
                result, extra = result[:2], dict(result[2] or {})
            if not (isinstance(result, tuple) and len(result) == 2):
                raise MethodError(f"method {self.name}: must return (vertices, faces) or "
                                  f"(vertices, faces, extra), got {type(result).__name__}")
            vertices, faces = result
        elif self.kind == "command":
            vertices, faces = _run_command(self, p, vd, hd, params)
            extra = {}
        else:
            raise MethodError(f"method {self.name} is built in: run it through benchmarks.bench")
        total = time.perf_counter() - t0
        vertices, faces = _check_mesh(self.name, vertices, faces)
        times = {k: float(v) for k, v in dict(extra.pop("times", None) or {}).items()}
        times["total"] = total
        return vertices, faces, extra, times


def _number(text: str):
    for kind in (int, float):
        try:
            return kind(text)
        except ValueError:
            pass
    return text


def _convert(method, name, text, default):
    try:
        if isinstance(default, bool):
            if text.lower() not in ("true", "false", "1", "0", "yes", "no"):
                raise ValueError
            return text.lower() in ("true", "1", "yes")
        return type(default)(float(text)) if isinstance(default, float) else type(default)(text)
    except (TypeError, ValueError):
        raise MethodError(f"method {method}: parameter {name}={text!r}: expected a "
                          f"{type(default).__name__}") from None


def _check_mesh(name, vertices, faces):
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not np.isfinite(v).all():
        raise MethodError(f"method {name}: vertices must be a finite (V, 3) array, got {v.shape}")
    if f.size == 0:
        raise MethodError(f"method {name}: returned no triangles")
    if f.ndim != 2 or f.shape[1] != 3 or not np.issubdtype(f.dtype, np.integer) \
            or f.min() < 0 or f.max() >= len(v):
        raise MethodError(f"method {name}: faces must be a (F, 3) int array of vertex indices, "
                          f"got {f.shape} {f.dtype}")
    return v, f.astype(np.int64)


def write_points(path, points, view_dir, head) -> Path:
    """A binary PLY of the points, view directions and heads only (what an external method gets)."""
    path = Path(path)
    rec = np.zeros(len(points), dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("vx", "<f4"),
                                       ("vy", "<f4"), ("vz", "<f4"), ("head", "<i2")])
    for i, axis in enumerate("xyz"):
        rec[axis] = points[:, i]
        rec["v" + axis] = view_dir[:, i]
    rec["head"] = head
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(rec)}\n"
              "property double x\nproperty double y\nproperty double z\nproperty float vx\n"
              "property float vy\nproperty float vz\nproperty short head\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(rec.tobytes())
    return path


def _run_command(method: Method, points, view_dir, head, params):
    import trimesh

    with tempfile.TemporaryDirectory(prefix="bodyscan-method-") as tmp:
        cloud, out = Path(tmp) / "cloud.ply", Path(tmp) / "mesh.ply"
        write_points(cloud, points, view_dir, head)
        values = {"cloud": str(cloud), "out": str(out), **{k: str(v) for k, v in params.items()}}
        try:
            argv = [token.format(**values) for token in shlex.split(method.target)]
        except (ValueError, KeyError, IndexError) as exc:
            raise MethodError(f"method {method.name}: bad command template "
                              f"{method.target!r} ({exc})") from None
        try:
            proc = subprocess.run(argv, capture_output=True, text=True, timeout=COMMAND_TIMEOUT_S)
        except FileNotFoundError:
            raise MethodError(f"method {method.name}: command not found: {argv[0]}") from None
        except subprocess.TimeoutExpired:
            raise MethodError(f"method {method.name}: the command ran over {COMMAND_TIMEOUT_S} s") \
                from None
        last = (proc.stderr.strip().splitlines() or proc.stdout.strip().splitlines() or [""])[-1]
        if proc.returncode != 0:
            raise MethodError(f"method {method.name}: the command exited with status "
                              f"{proc.returncode}" + (f": {last}" if last else ""))
        if not out.is_file() or out.stat().st_size == 0:
            raise MethodError(f"method {method.name}: the command wrote no mesh to {{out}}"
                              + (f" ({last})" if last else ""))
        try:
            mesh = trimesh.load(out, force="mesh", process=False)
        except Exception as exc:
            raise MethodError(f"method {method.name}: cannot read the mesh the command wrote "
                              f"({type(exc).__name__}: {exc})") from None
        return np.asarray(mesh.vertices, np.float64), np.asarray(getattr(mesh, "faces", []))


def builtin_methods() -> dict:
    """Built-in method name -> kind, in table order (`benchmarks.bench.RECON_METHODS`, then the
    peers): adding a built-in method is one line there or in `benchmarks.peers.PEERS`."""
    from .bench import RECON_METHODS
    from .peers import PEERS

    return {**{m: "recon" for m in RECON_METHODS}, **{m: "peer" for m in PEERS}}


def installed_methods() -> dict:
    """Entry points of the group ``bodyscan.methods``: name -> ``module:function``."""
    from importlib.metadata import entry_points

    return {ep.name: ep.value.replace(" ", "") for ep in entry_points(group=ENTRY_POINT_GROUP)}


def method_name(spec: str) -> str:
    """The table name of a method spec, without importing anything."""
    spec = str(spec).strip()
    named = _NAMED.match(spec)
    if named and (named.group(2).startswith("cmd:") or _CALLABLE.match(named.group(2))):
        return named.group(1)
    if spec.startswith("cmd:"):
        tokens = shlex.split(spec[4:]) or ["cmd"]
        return Path(tokens[0]).name
    return spec


def resolve(spec: str) -> Method:
    """The `Method` of a spec (see the module docstring).

    Raises
    ------
    MethodError
        Unknown name, or a malformed spec.
    """
    spec = str(spec).strip()
    name = method_name(spec)
    body = spec[len(name) + 1:] if spec.startswith(name + "=") else spec
    builtin = builtin_methods()
    if body in builtin:
        return Method(body, spec, builtin[body])
    if body.startswith("cmd:"):
        template = body[4:].strip()
        try:
            tokens = shlex.split(template)
        except ValueError as exc:
            raise MethodError(f"method command {template!r}: {exc}") from None
        if "{cloud}" not in template or "{out}" not in template or not tokens:
            raise MethodError(f"method command {template!r} must contain {{cloud}} and {{out}}")
        return Method(name, spec, "command", template)
    if _CALLABLE.match(body):
        return Method(name, spec, "python", body)
    installed = installed_methods()
    if body in installed:
        return Method(body, spec, "python", installed[body])
    known = list(builtin) + list(installed)
    raise MethodError(f"unknown method {spec!r} (built in or installed: {', '.join(known)}; "
                      "or your own: module:function, or --method-cmd 'TOOL {cloud} {out}')")


def command_spec(template: str) -> str:
    """The spec of ``--method-cmd TEMPLATE`` (``NAME=TEMPLATE`` names it)."""
    template = str(template).strip()
    named = _NAMED.match(template)
    if named and " " not in named.group(1) and "{" not in named.group(1):
        return f"{named.group(1)}=cmd:{named.group(2).strip()}"
    return "cmd:" + template
