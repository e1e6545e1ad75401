"""Base for every configuration model: strict, immutable, with clear errors.

Section models live beside the code they configure (``flight/settings.py``,
``sensors/gnss/settings.py`` ...); ``config.py`` composes them and loads TOML.
Every model derives from :class:`StrictModel`, so an unknown key is an error
that names the key path, and nothing can be changed after validation.
:func:`read_json` reads what the package stored (manifests, run logs) the same way.
"""

from __future__ import annotations

import argparse
import json
import sys
import types
import typing
from pathlib import Path
from typing import Callable

import re

from pydantic import AfterValidator, BaseModel, ConfigDict, TypeAdapter, ValidationError, model_validator


class StrictModel(BaseModel):
    """Unknown keys are errors; instances are frozen; numbers must be finite.

    No coercion between kinds: a string or a boolean is never read as a number, and
    only ``true``/``false`` are booleans (``"4.86"``, ``"yes"`` and ``1`` are errors).
    Lists may stand for tuples (TOML has no tuples).
    """

    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, allow_inf_nan=False,
                              validate_default=True)

    @model_validator(mode="before")
    @classmethod
    def _no_kind_coercion(cls, data):
        if isinstance(data, dict):
            for name, field in cls.model_fields.items():
                key = field.alias or name
                if key in data:
                    problem = _kind_problem(data[key], field.annotation)
                    if problem:  # the key rides in the message; format_validation_error puts it in the path
                        sub, why, got = problem
                        raise ValueError(f"[{key}{sub}] {why} (got {got!r})")
        return data


def _scalar_kind(tp) -> str | None:
    """'bool' or 'number' for an annotation that admits only that (None/Annotated unwrapped)."""
    origin = typing.get_origin(tp)
    if origin is typing.Annotated:
        return _scalar_kind(typing.get_args(tp)[0])
    if origin in (typing.Union, types.UnionType):
        kinds = {_scalar_kind(a) for a in typing.get_args(tp) if a is not type(None)}
        return kinds.pop() if len(kinds) == 1 else None
    if tp is bool:
        return "bool"
    if tp in (int, float):
        return "number"
    return None


def _kind_problem(value, tp) -> tuple[str, str, object] | None:
    """(sub-path, why, value) when ``value`` may not stand for ``tp`` (a bool/number field,
    or a list/tuple of them); None when it may."""
    kind = _scalar_kind(tp)
    if kind == "bool" and not isinstance(value, bool):
        return "", "expected true or false", value
    if kind == "number" and isinstance(value, (str, bool)):
        return "", "expected a valid number, not " + ("a string" if isinstance(value, str) else "true/false"), value
    base = tp
    while typing.get_origin(base) is typing.Annotated:  # a constrained list or tuple: its elements' kinds
        base = typing.get_args(base)[0]
    if typing.get_origin(base) in (typing.Union, types.UnionType):
        args = [a for a in typing.get_args(base) if a is not type(None)]
        base = args[0] if len(args) == 1 else None
    if typing.get_origin(base) in (list, tuple) and isinstance(value, (list, tuple)):
        elems = [a for a in typing.get_args(base) if a is not Ellipsis]
        if len(set(elems)) == 1:
            for k, v in enumerate(value):
                p = _kind_problem(v, elems[0])
                if p:
                    return f".{k}{p[0]}", p[1], p[2]
    return None


def _file_name(v: str) -> str:
    if not v or v.startswith(".") or "/" in v or "\\" in v or not v.isprintable() or len(v) > 100:
        raise ValueError("expected a name without '/' or '\\' that does not start with '.' (it names the default "
                         "output files and folders, which must stay inside theirs), at most 100 printable characters")
    return v


#: a name the default output paths are made of (``runs/<name>-seed0.rrd``, ``campaigns/<name>``)
FileName = typing.Annotated[str, AfterValidator(_file_name)]

#: no point of an airframe is this far from its centre of gravity: the largest aircraft flown, the
#: Antonov An-225, is 84 m long with an 88 m span
MAX_LEVER_ARM_M = 100.0


def _lever_arm(v: tuple[float, float, float]) -> tuple[float, float, float]:
    length = sum(x * x for x in v) ** 0.5
    if length > MAX_LEVER_ARM_M:
        raise ValueError(f"a lever arm of {length:.6g} m: expected at most {MAX_LEVER_ARM_M:g} m from the CG (the "
                         f"largest aircraft, the An-225, is 84 m long with an 88 m span; metres, body axes)")
    return v


#: a sensor's position from the CG, body axes (m): finite (as every number) and on the airframe
LeverArm = typing.Annotated[tuple[float, float, float], AfterValidator(_lever_arm)]


class ConfigError(ValueError):
    """A configuration file failed to load or validate.

    The message lists every problem as ``file: key.path: what was expected``.
    """

    def __init__(self, source: str | Path, problems: list[str]) -> None:
        self.source = str(source)
        self.problems = list(problems)
        lines = "\n".join(f"  {self.source}: {p}" for p in self.problems)
        super().__init__(f"{len(self.problems)} problem(s) in {self.source}:\n{lines}")


def arg_in_range(kind, lo, hi):
    """An argparse type: a ``kind`` number in [lo, hi) (argparse names the option, prints the message and exits
    2 before any work)."""
    def parse(text: str):
        try:
            v = kind(text)
        except ValueError:
            v = None
        if v is None or not lo <= v < hi:
            what = {"int": "an integer", "float": "a number"}.get(kind.__name__, f"a {kind.__name__}")
            raise argparse.ArgumentTypeError(f"expected {what} in [{show(lo)}, {show(hi)}), got {text!r}")
        return v

    def show(x) -> str:
        return f"{x:g}" if isinstance(x, float) else str(x)

    return parse


def exit_code(command: Callable[[], int]) -> int:
    """Run a command-line command: its exit code; 2 with the ConfigError's message on stderr; 130 on Ctrl-C
    (the shell's code for SIGINT). Never a traceback for either."""
    try:
        return command()
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        for note in getattr(exc, "__notes__", ()):  # what was and was not written (testbed.outputs)
            print(f"  {note}", file=sys.stderr)
        return 2
    except KeyboardInterrupt as exc:
        notes = getattr(exc, "__notes__", ())  # a command with outputs says what it left (testbed.outputs)
        print(f"interrupted: {'; '.join(notes) if notes else 'the command had not written anything'}",
              file=sys.stderr)
        return 130


def read_json(path: str | Path, model, *, what: str, remedy: str):
    """A JSON file this package stored (a manifest, a run log), validated like an input: the value of
    ``model`` (a pydantic model or ``TypeAdapter``), or a :class:`ConfigError` naming the file, every key
    path, the value and what was expected, then ``remedy`` (what to do about it). Never a traceback for a
    file damaged or edited since it was written."""
    path, then = Path(path), [remedy] if remedy else []
    try:
        data = json.loads(path.read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ConfigError(path, [f"cannot be read as {what} ({exc})"] + then) from None
    adapter = model if isinstance(model, TypeAdapter) else TypeAdapter(model)
    try:
        return adapter.validate_python(data)
    except ValidationError as err:
        raise ConfigError(path, [f"not {what}: {p}" for p in format_validation_error(err, data)] + then) from None


def _file_path(loc: tuple, data) -> list:
    """``loc`` without the union tags that are not keys of ``data``."""
    out, cur = [], data
    for part in loc:
        if isinstance(cur, dict) and part in cur:
            cur = cur[part]
        elif isinstance(cur, list) and isinstance(part, int) and 0 <= part < len(cur):
            cur = cur[part]
        elif isinstance(cur, dict) and isinstance(part, str) and part in [str(v) for v in cur.values()]:
            continue  # a discriminator value, not a key of the file
        else:
            cur = None
        out.append(part)
    return out


_KEYED = re.compile(r"^Value error, \[([^\]]+)\] (.*)$", re.S)


def format_validation_error(err: ValidationError, data=None) -> list[str]:
    """Turn a pydantic error into ``key.path: message (got value)`` lines.

    data : the validated input, if at hand: a tagged union's tag that pydantic puts in the
    path (``faults.0.gps_step.bias_m``) is dropped, so the path is the file's (``faults.0.bias_m``).
    """
    out = []
    for e in err.errors():
        loc = ".".join(str(p) for p in _file_path(e["loc"], data))
        msg = e["msg"]
        kind = _KEYED.match(msg)
        if kind:  # a StrictModel kind check: the key is part of the path, the value is in the message
            out.append(f"{loc + '.' if loc else ''}{kind.group(1)}: {kind.group(2)}")
            continue
        loc = loc or "<top level>"
        msg = msg.removeprefix("Value error, ")  # pydantic's wrapping of a validator's message
        if e["type"] == "extra_forbidden":
            msg = "unknown key (check the spelling; see docs/reference/configuration.md)"
        got = e.get("input")
        got_s = "" if e["type"] in ("missing", "extra_forbidden") else f" (got {got!r})"
        if len(got_s) > 120:
            got_s = got_s[:117] + "...)"
        out.append(f"{loc}: {msg}{got_s}")
    return out
