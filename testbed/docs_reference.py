"""The configuration reference page, generated from the settings models.

Every TOML file the testbed reads is validated by a :class:`~testbed.schema.StrictModel`;
this module walks those models (nested tables, arrays of tables, tagged unions) and
writes one Markdown table per TOML table: every key with its type, default, unit,
allowed values (from the ``Field`` constraints and ``Literal`` choices) and its
``description``. Regenerate the page after changing a model::

    python -m testbed.docs_reference > docs/reference/configuration.md

``tests/test_docs_reference.py`` fails when the committed page differs from a fresh
generation, or when a field has no description.

For docs/reference/api.md (mkdocstrings), :func:`numpy_prose` and the griffe extension
``testbed.docs_reference:NumpyProse`` read the project's numpy-style docstrings, which put
a parameter's description where numpydoc puts its type.
"""

from __future__ import annotations

import datetime as dt
import functools
import importlib
import inspect
import json
import re
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import annotated_types as at
from pydantic import BaseModel
from pydantic.fields import FieldInfo

from testbed.markdown import table as md_table
from testbed.monitors import entry, monitor_names

COMMAND = "python -m testbed.docs_reference > docs/reference/configuration.md"

#: the table of each monitor's own options (``[monitor.<name>]``), composed from the registry
MONITOR_TABLES = "monitor"


@dataclass(frozen=True)
class FileKind:
    """One kind of configuration file: its root model and where such files live."""

    key: str  # anchor prefix
    title: str
    model: str  # "module:Class"
    intro: str


FILE_KINDS = (
    FileKind("approach", "Approach file", "testbed.config:ApproachConfig",
             "`approaches/<name>.toml`, or any path given to `testbed fly`, `testbed check`, a campaign spec's "
             "`approaches`. Top-level keys come before the first `[table]`."),
    FileKind("aircraft", "Aircraft file", "testbed.flight.settings:AircraftSettings",
             "`aircraft/<name>/aircraft.toml`, named by an approach file's `aircraft` key. Body axes: x forward, "
             "y right, z down (FRD)."),
    FileKind("campaign", "Campaign spec", "testbed.campaign.spec:CampaignSpec",
             "`approaches/campaigns/<name>.toml`, or any path given to `testbed campaign`. Each cell of the sweep "
             "is an approach file with the sweep's values applied, validated like one."),
    FileKind("monitor", "Monitor configuration file", "testbed.rinex.settings:MonitorFileConfig",
             "The file given to `testbed monitor --config`."),
)

#: unit by key-name suffix, longest first (the project's naming convention)
UNIT_SUFFIXES = (
    ("_m_s_sqrt_s", "m/s/√s"), ("_rad_sqrt_s", "rad/√s"), ("_m2_s3", "m²/s³"), ("_m2_s", "m²/s"),
    ("_deg_h_s", "deg/h/s"), ("_deg_h", "deg/h"), ("_m_s3", "m/s³"), ("_m_s2", "m/s²"), ("_rad_s", "rad/s"), ("_m_s", "m/s"), ("_per_km2", "1/km²"), ("_chips", "chip rates"),
    ("_deg", "deg"), ("_hz", "Hz"), ("_kt", "kt"), ("_px", "px"), ("_db", "dB"), ("_mm", "mm"),
    ("_ppm", "ppm"), ("_m", "m"), ("_s", "s"),
)
#: heights without the _m suffix (WGS84 ellipsoidal, metres)
HEIGHT_KEYS = ("h", "end_h", "centre_h")


def unit(name: str) -> str:
    """The unit a key's name gives (``speed_kt`` -> kt); '' when the name gives none."""
    if name in HEIGHT_KEYS:
        return "m"
    for suffix, u in UNIT_SUFFIXES:
        if name.endswith(suffix):
            return u
    return ""


# --------------------------------------------------------------------------- types
def _is_model(tp) -> bool:
    return isinstance(tp, type) and issubclass(tp, BaseModel)


def _unwrap(tp) -> tuple[Any, list]:
    """(type without Annotated, its constraint metadata)."""
    meta: list = []
    while typing.get_origin(tp) is typing.Annotated:
        args = typing.get_args(tp)
        tp = args[0]
        for m in args[1:]:
            meta.extend(m.metadata if isinstance(m, FieldInfo) else [m])
    return tp, meta


def _discriminator(tp) -> str | None:
    while typing.get_origin(tp) is typing.Annotated:
        for m in typing.get_args(tp)[1:]:
            if isinstance(m, FieldInfo) and isinstance(m.discriminator, str):
                return m.discriminator
        tp = typing.get_args(tp)[0]
    return None


def _arms(tp) -> list:
    """The arms of a union (None dropped), or [tp]."""
    tp, _ = _unwrap(tp)
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        return [a for a in typing.get_args(tp) if a is not type(None)]
    return [tp]


def _models(tp) -> list[type[BaseModel]]:
    """Every model class inside ``tp``, in order."""
    tp, _ = _unwrap(tp)
    if _is_model(tp):
        return [tp]
    out: list = []
    for a in typing.get_args(tp):
        for m in _models(a):
            if m not in out:
                out.append(m)
    return out


_SCALARS = {bool: "boolean", int: "integer", float: "float", str: "string", dt.datetime: "date-time",
            Path: "path", typing.Any: "any"}


def _plural(text: str) -> str:
    if " or " in text and not text.startswith("array"):
        return " or ".join(_plural(p) for p in text.split(" or "))
    if text.startswith("array"):
        return "arrays" + text[len("array"):]
    if text.startswith("["):
        return text + " arrays"
    return text + "s"


def type_text(tp) -> str:
    """A TOML reading of an annotation: ``float``, ``array of 3 floats``, ``integer or string`` ..."""
    tp, _ = _unwrap(tp)
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        parts: list[str] = []
        for a in args:
            if a is type(None):
                continue
            t = type_text(a)
            if t not in parts:
                parts.append(t)
        return parts[0] if len(parts) == 1 else ", ".join(parts[:-1]) + " or " + parts[-1]
    if origin is typing.Literal:
        kinds = []
        for v in args:
            k = _SCALARS.get(type(v), "string")
            if k not in kinds:
                kinds.append(k)
        return " or ".join(kinds)
    if origin is list or (origin is tuple and len(args) == 2 and args[1] is Ellipsis):
        return "array of " + _plural(type_text(args[0]))
    if origin is tuple:
        texts = [type_text(a) for a in args]
        if len(set(texts)) == 1:
            return f"array of {len(texts)} {_plural(texts[0])}"
        return "[" + ", ".join(texts) + "]"
    if origin is dict:
        return f"table ({type_text(args[0])} keys, {type_text(args[1])} values)"
    if _is_model(tp):
        return "table"
    for k, v in _SCALARS.items():
        if tp is k:
            return v
    return getattr(tp, "__name__", str(tp))


# --------------------------------------------------------------------------- values
def num(x) -> str:
    """A bound for the Allowed column: 0, 0.5, 150000, 1e-7, 1e10."""
    if isinstance(x, bool) or not isinstance(x, float):
        return str(x)
    if x.is_integer() and abs(x) < 1e6:
        return str(int(x))
    return _exp(_short(x))


def _short(x: float) -> str:
    """repr, but a large round number as 1e10 (exact: only when the digits allow it)."""
    if x.is_integer() and abs(x) >= 1e6:
        digits = str(int(abs(x)))
        sig = digits.rstrip("0")
        if len(sig) <= 3:
            mant = sig[0] + ("." + sig[1:] if len(sig) > 1 else "")
            return ("-" if x < 0 else "") + f"{mant}e{len(digits) - 1}"
    return repr(x)


def _exp(r: str) -> str:
    if "e" not in r:
        return r
    mant, e = r.split("e")
    return f"{mant}e{int(e)}"


def _toml_float(x: float) -> str:
    r = _exp(_short(float(x)))
    return r if "e" in r or "." in r or "n" in r else r + ".0"


def _toml_key(k) -> str:
    if isinstance(k, (int, float)) and not isinstance(k, bool):
        return json.dumps(num(float(k)))
    k = str(k)
    return k if re.fullmatch(r"[A-Za-z0-9_-]+", k) else json.dumps(k, ensure_ascii=False)


def toml_value(v) -> str:
    """``v`` written as a TOML value (what a file would say)."""
    if isinstance(v, BaseModel):
        return toml_value(v.model_dump(exclude_unset=True))
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        return _toml_float(v)
    if isinstance(v, dt.datetime):
        return v.isoformat().replace("+00:00", "Z")
    if isinstance(v, (str, Path)):
        return json.dumps(str(v), ensure_ascii=False)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        if not v:
            return "{}"
        return "{ " + ", ".join(f"{_toml_key(k)} = {toml_value(x)}" for k, x in v.items()) + " }"
    return json.dumps(str(v))


def _bounds(meta: list) -> str:
    lo = hi = None
    for m in meta:
        if isinstance(m, at.Interval):
            meta = meta + [c for c in (at.Gt(m.gt) if m.gt is not None else None,
                                       at.Ge(m.ge) if m.ge is not None else None,
                                       at.Lt(m.lt) if m.lt is not None else None,
                                       at.Le(m.le) if m.le is not None else None) if c is not None]
    for m in meta:
        if isinstance(m, at.Ge):
            lo = ("[", m.ge)
        elif isinstance(m, at.Gt):
            lo = ("(", m.gt)
        elif isinstance(m, at.Le):
            hi = ("]", m.le)
        elif isinstance(m, at.Lt):
            hi = (")", m.lt)
    if lo and hi:
        return f"{lo[0]}{num(lo[1])}, {num(hi[1])}{hi[0]}"
    if lo:
        return ("≥ " if lo[0] == "[" else "> ") + num(lo[1])
    if hi:
        return ("≤ " if hi[0] == "]" else "< ") + num(hi[1])
    return ""


def _lengths(meta: list, one: str, many: str) -> str:
    lo = next((m.min_length for m in meta if isinstance(m, at.MinLen)), None)
    hi = next((m.max_length for m in meta if isinstance(m, at.MaxLen)), None)
    if lo and hi:
        return f"{lo} to {hi} {many}"
    if lo:
        return f"at least {lo} {one if lo == 1 else many}"
    if hi:
        return f"at most {hi} {one if hi == 1 else many}"
    return ""


def _literals(tp) -> list:
    tp, _ = _unwrap(tp)
    if typing.get_origin(tp) is typing.Literal:
        return list(typing.get_args(tp))
    out: list = []
    if typing.get_origin(tp) in (typing.Union, types.UnionType):
        for a in typing.get_args(tp):
            out += [v for v in _literals(a) if v not in out]
    return out


def _choices(tp) -> str:
    """The Literal values of ``tp``: the only ones when every arm is a Literal, else the special values
    of a kind (``string: "random"``), or besides any value of that kind (``"random" or any string``)."""
    choices = _literals(tp)
    if not choices:
        return ""
    listed = ", ".join(f"`{toml_value(c)}`" for c in choices)
    others = [a for a in _arms(tp) if typing.get_origin(_unwrap(a)[0]) is not typing.Literal]
    if not others:
        return listed
    kind = type_text(typing.Literal[tuple(choices)])
    if kind in [type_text(a) for a in others]:
        return f"{listed} or any {kind}"
    return f"{kind}: {listed}"


def allowed_text(tp, meta: list) -> str:
    """Bounds, lengths, choices and per-element rules of a field, as one cell."""
    parts = [t for t in (_choices(tp), _bounds(meta)) if t]
    base, inner = _unwrap(tp)
    arms = _arms(base)
    seq = next((a for a in arms if typing.get_origin(_unwrap(a)[0]) in (list, tuple, dict)), None)
    if seq is not None:
        n = _lengths(meta + inner, "entry", "entries")
        if n:
            parts.append(n)
        elems = [a for a in typing.get_args(_unwrap(seq)[0]) if a is not Ellipsis]
        if typing.get_origin(_unwrap(seq)[0]) is not dict and elems:
            each = {allowed_text(a, _unwrap(a)[1]) for a in elems}
            if len(each) == 1 and "" not in each:
                text = each.pop()
                parts.append(("each one of " if text.startswith("`") else "each ") + text)
    elif str in [_unwrap(a)[0] for a in arms]:
        n = _lengths(meta + inner, "character", "characters")
        if n:
            parts.append(n)
    return "; ".join(parts)


# --------------------------------------------------------------------------- text
_ROLE = re.compile(r":[a-z]+:`(~?)([^`]+)`")
_DOCS_REF = re.compile(r"docs/([\w/.-]+?\.md)(?:\s*§([A-Za-z][\w-]*))?")


def rst_to_md(text: str, package: str = "testbed") -> str:
    """The docstring markup the models use (``code``, :role:`target`) as Markdown; a relative target
    (``.features``) is resolved in ``package``; ``docs/<page>.md §anchor`` references become links
    relative to docs/reference/."""
    text = text.replace("``", "`")
    text = _ROLE.sub(lambda m: f"`{_role_target(m, package)}`", text)

    def link(m: re.Match) -> str:
        target = "../" + m.group(1) + (f"#{m.group(2)}" if m.group(2) else "")
        return f"[{m.group(0)}]({target})"

    return _outside_code(text, lambda s: _DOCS_REF.sub(link, s))


def _role_target(m: re.Match, package: str) -> str:
    """What a reST role shows: ``~a.b.C`` -> ``C``; a relative ``.mod`` resolved in ``package``."""
    tilde, target = m.group(1), m.group(2)
    if tilde:
        return target.rsplit(".", 1)[-1]
    return package + target if target.startswith(".") else target


def _outside_code(text: str, fn) -> str:
    parts = text.split("`")
    return "`".join(fn(p) if i % 2 == 0 else p for i, p in enumerate(parts))


def cell(text: str) -> str:
    """Text fit for one Markdown table cell."""
    text = " ".join(rst_to_md(text).split())
    return _outside_code(text, lambda s: s.replace("|", "\\|").replace("*", "\\*").replace("<", "&lt;"))


def docstring(cls) -> str:
    doc = cls.__dict__.get("__doc__")
    return rst_to_md(inspect.cleandoc(doc), cls.__module__.rpartition(".")[0]) if doc else ""


# --------------------------------------------------------------------------- walk
@dataclass
class Section:
    anchor: str
    heading: str
    intro: str
    model: type[BaseModel]
    rows: list[tuple[str, ...]] = field(default_factory=list)


@dataclass
class _Walk:
    sections: list[Section] = field(default_factory=list)
    documented: dict[type, str] = field(default_factory=dict)  # model -> anchor of its first section


def _anchor(*parts: str) -> str:
    return "-".join(re.sub(r"[^a-z0-9]+", "-", p.lower()).strip("-") for p in parts if p)


def _is_monitor_tables(name: str, path: tuple[str, ...]) -> bool:
    return not path and name == MONITOR_TABLES


def walk(kind: FileKind, w: _Walk) -> None:
    module, cls = kind.model.split(":")
    root = getattr(importlib.import_module(module), cls)
    _table(w, kind, root, (), array=False, tag=None, skip=(), note="")


def _table(w: _Walk, kind: FileKind, model: type[BaseModel], path: tuple[str, ...], *, array: bool,
           tag: tuple[str, str] | None, skip: tuple[str, ...], note: str, inline: bool = False) -> str:
    dotted = ".".join(path)
    anchor = _anchor(kind.key, *path, *(tag or ()))
    if not path:
        heading = f"{kind.title}: top-level keys"
    elif inline:
        heading = f"Entries of `{dotted}`"
    else:
        heading = f"`[[{dotted}]]`" if array else f"`[{dotted}]`"
    if tag:
        heading += f" with `{tag[0]} = {toml_value(tag[1])}`"
    intro = docstring(model)
    if note:
        intro = (intro + "\n\n" + note).strip()
    sec = Section(anchor, heading, intro, model)
    w.sections.append(sec)
    w.documented.setdefault(model, anchor)
    children: list = []
    fields = list(model.model_fields.items())
    if tag:  # the tag first, as a file writes it
        fields.sort(key=lambda nf: nf[0] != tag[0])
    for name, f in fields:
        if name in skip:
            continue
        desc = f.description or ""
        tp = f.annotation
        if _is_monitor_tables(name, path):
            links = []
            for monitor in monitor_names():
                a = _anchor("approach", name, monitor)
                links.append(f"[`[{name}.{monitor}]`](#{a})")
                if kind.key == "approach":
                    children.append((f"{name}.{monitor}", entry(monitor).options, False, None, (),
                                     f"The `{monitor}` monitor's own options.", False))
            sec.rows.append((name, "tables: " + ", ".join(links), "optional", "", "", cell(desc)))
            continue
        models = _models(tp)
        if models:
            ttext, links = _structure(w, kind, path, name, tp, children)
            default = "required" if f.is_required() else _default(f, tp)
            sec.rows.append((name, f"{ttext}: {links}", default, unit(name), cell(allowed_text(tp, f.metadata)),
                             cell(desc)))
            continue
        sec.rows.append((name, type_text(tp), _default(f, tp), unit(name), cell(allowed_text(tp, f.metadata)),
                         cell(desc)))
    for name, sub, arr, sub_tag, sub_skip, sub_note, sub_inline in children:
        _table(w, kind, sub, path + (name,), array=arr, tag=sub_tag, skip=sub_skip, note=sub_note,
               inline=sub_inline)
    return anchor


def _join(path: tuple[str, ...], name: str) -> str:
    return ".".join(path + (name,))


def _structure(w: _Walk, kind: FileKind, path: tuple[str, ...], name: str, tp, children: list) -> tuple[str, str]:
    """Type text and links of a field holding models; queues the tables to document in ``children``."""
    base, _ = _unwrap(tp)
    arms = _arms(base)
    dotted = _join(path, name)
    if len(arms) == 1 and _is_model(arms[0]):  # a table
        a = _anchor(kind.key, *path, name)
        children.append((name, arms[0], False, None, (), "", False))
        return "table", f"[`[{dotted}]`](#{a})"
    if len(arms) == 1 and typing.get_origin(arms[0]) is list:
        item = typing.get_args(arms[0])[0]
        variants = _arms(item)
        disc = _discriminator(item)
        if all(_is_model(v) for v in variants):
            links = []
            for v in variants:
                tag = (disc, typing.get_args(v.model_fields[disc].annotation)[0]) if disc else None
                a = _anchor(kind.key, *path, name, *(tag or ()))
                children.append((name, v, True, tag, (), "", False))
                links.append(f"[`{tag[1]}`](#{a})" if tag else f"[`[[{dotted}]]`](#{a})")
            if disc:
                return f"array of tables `[[{dotted}]]` by `{disc}`", ", ".join(links)
            return "array of tables", ", ".join(links)
    # models deeper inside (an array of arrays of tables): link to where they are documented
    links = []
    for m in _models(base):
        if m not in w.documented:
            disc = _discriminator_of(m)
            tag = (disc, typing.get_args(m.model_fields[disc].annotation)[0]) if disc else None
            children.append((name, m, False, tag, (), "", True))
            a = _anchor(kind.key, *path, name, *(tag or ()))
        else:
            a = w.documented[m]
        links.append(f"[{_model_label(m)}](#{a})")
    return type_text(base).replace("table", "inline table"), ", ".join(links)


def _discriminator_of(model: type[BaseModel]) -> str | None:
    for n, f in model.model_fields.items():
        lit = _unwrap(f.annotation)[0]
        if typing.get_origin(lit) is typing.Literal and len(typing.get_args(lit)) == 1 and f.is_required():
            return n
    return None


def _model_label(model: type[BaseModel]) -> str:
    disc = _discriminator_of(model)
    if disc:
        return f"`{disc} = {toml_value(typing.get_args(model.model_fields[disc].annotation)[0])}`"
    return f"`{model.__name__}`"


def _default(f: FieldInfo, tp) -> str:
    if f.is_required():
        return "required"
    v = f.get_default(call_default_factory=True)
    if v is None:
        return "unset"
    if isinstance(v, BaseModel) and _is_model(_unwrap(tp)[0]):
        return "optional"
    return f"`{toml_value(v)}`"


# --------------------------------------------------------------------------- page
def sections() -> list[tuple[FileKind, list[Section]]]:
    w = _Walk()
    out = []
    for kind in FILE_KINDS:
        start = len(w.sections)
        walk(kind, w)
        out.append((kind, w.sections[start:]))
    return out


HEADER = ["Key", "Type", "Default", "Unit", "Allowed", "Description"]


def render() -> str:
    """The whole page (deterministic: fields in definition order, no clock, no paths of this checkout)."""
    lines = [
        "# Configuration reference",
        "",
        f"*Generated from the configuration models by `{COMMAND}`. Edit the models' `description=` texts, "
        "then regenerate; do not edit this page by hand.*",
        "",
        "How to write these files, with a worked example: [Configuration](../guide/configuration.md).",
        "",
        "## Conventions",
        "",
        "- Every file is TOML. An unknown key is an error that names the file and the key path "
        "(`testbed check FILE` lists every problem).",
        "- No kind is read as another: `\"4.86\"` is not a number, `1` and `\"yes\"` are not booleans. "
        "Numbers must be finite (no `nan`, `inf`). An integer may stand for a float.",
        "- An array may stand for a fixed-length tuple (TOML has none); a table may be written inline "
        "(`camera = { preset = \"approach-1080p\" }`) or as a `[section]`.",
        "- **Unit** is the one the key's name gives (`_m` metres, `_s` seconds, `_deg` degrees, `_kt` knots, "
        "`_hz` hertz, `_px` pixels, `_db` decibels, `_m_s` m/s ...). Keys without a unit suffix give theirs "
        "in the description.",
        "- **Default** `unset` means the key is left out (TOML has no null; a description's \"None\" is "
        "that case). `required` keys have no default.",
        "- **Allowed**: `[a, b]` closed interval, `(a, b)` open, `≥ a`, `> a`; quoted values are the "
        "only choices; further rules between keys are checked too and named in the error.",
        "- Paths are relative to the file that names them, not to the working folder.",
        "",
    ]
    all_secs = sections()
    anchors = [s.anchor for _, secs in all_secs for s in secs]
    dup = sorted({a for a in anchors if anchors.count(a) > 1})
    if dup:
        raise RuntimeError(f"anchors used twice: {dup}")
    for kind, secs in all_secs:
        lines += [f"## {kind.title}", "", kind.intro, ""]
        for s in secs:
            lines += [f'<a id="{s.anchor}"></a>', "", f"### {s.heading}", ""]
            if s.intro:
                lines += [s.intro, ""]
            lines += md_table(HEADER, [[f"`{key}`", *rest] for key, *rest in s.rows])
            lines.append("")
    return "\n".join(lines).rstrip("\n") + "\n"


# --------------------------------------------------------------------------- API page
#: numpy sections whose items are ``name : ...``
_ITEM_SECTIONS = {"parameters", "other parameters", "attributes", "returns", "yields", "receives"}
_RETURN_SECTIONS = {"returns", "yields", "receives"}
_ITEM = re.compile(r"^(?P<names>\*{0,2}[A-Za-z_]\w*(?:, \*{0,2}[A-Za-z_]\w*)*) : (?P<text>\S.*)$")
_DASHES = re.compile(r"\s*-{3,}\s*")


def numpy_prose(text: str) -> str:
    """A docstring in the project's style, as numpydoc.

    The project writes numpy sections with the description where numpydoc puts the type
    (``seed : seeds every sensor draw``); this moves it onto the next line, indented, so a
    numpydoc reader shows it as the description (the type comes from the signature). A
    Returns section written as prose becomes one item described by it. reST roles
    (``:class:`~a.B` ``) become code spans, a ``::`` ending a line becomes ``:``, and ``>>>``
    examples become fenced code.
    """
    lines = text.split("\n")
    out: list[str] = []
    section, prose = None, False
    for i, line in enumerate(lines):
        if line.strip() and i + 1 < len(lines) and _DASHES.fullmatch(lines[i + 1]):
            section = line.strip().lower()
            first = next((x for x in lines[i + 2:] if x.strip()), "")
            prose = section in _RETURN_SECTIONS and not _ITEM.match(first)
            out.append(line)
            continue
        if prose:  # one unnamed item: its type from the signature, the prose its description
            if _DASHES.fullmatch(line):
                out += [line, ":"]
            else:
                out.append("    " + line if line.strip() else line)
            continue
        m = _ITEM.match(line) if section in _ITEM_SECTIONS else None
        if m and not (section in _RETURN_SECTIONS and "," in m["names"]):
            out += [m["names"] + (" :" if section in _RETURN_SECTIONS else ""), "    " + m["text"]]
        else:
            out.append(line)
    text = "\n".join(_fence_doctests(out))
    text = _ROLE.sub(lambda r: f"`{_role_target(r, '').lstrip('.')}`", text)
    return re.sub(r"(?<=\S)::$", ":", text, flags=re.M)


def _fence_doctests(lines: list[str]) -> list[str]:
    """Doctest blocks (from a ``>>>`` line to the next blank line) as fenced pycon code: Markdown
    would read ``>>>`` as nested quotes."""
    out: list[str] = []
    fenced = False
    for line in lines:
        if not fenced and line.startswith(">>>"):
            out += ["", "```pycon"] if out and out[-1].strip() else ["```pycon"]
            fenced = True
        elif fenced and not line.strip():
            out.append("```")
            fenced = False
        out.append(line)
    return out + (["```"] if fenced else [])


def __getattr__(name: str):
    # NumpyProse needs griffe (the docs extra); made on first use, so importing this module does not
    if name == "NumpyProse":
        return _numpy_prose_extension()
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


@functools.cache
def _numpy_prose_extension() -> type:
    import griffe

    class NumpyProse(griffe.Extension):
        """Griffe extension for docs/reference/api.md: reads the project's docstrings (:func:`numpy_prose`).

        In mkdocs.yml, in the python handler's options: ``extensions: [testbed.docs_reference:NumpyProse]``.
        """

        def on_instance(self, *, obj, **kwargs) -> None:
            if obj.docstring is not None:
                obj.docstring.value = numpy_prose(obj.docstring.value)

    return NumpyProse


def main() -> None:
    import sys

    sys.stdout.buffer.write(render().encode("utf-8"))  # UTF-8 whatever the terminal's locale


if __name__ == "__main__":
    main()
