"""Read a testbed recording back without a viewer (for scripts and tests).

Uses ``rerun.chunk.RrdReader`` (rerun-sdk ``catalog`` extra). Times are on the
``sim_time`` timeline, returned in seconds.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rerun.chunk as rrc


def _chunks(path: str | Path):
    return rrc.RrdReader(str(path)).stream()


def entity_paths(path: str | Path) -> set[str]:
    """Every entity path in the recording (with a leading '/')."""
    return {ch.entity_path for ch in _chunks(path)}


def content_digest(path: str | Path) -> str:
    """A digest of everything a recording holds except the ids Rerun makes per write.

    Rerun gives every chunk and row a TUID (a time-based unique id, ``rerun:id`` and
    ``rerun.controls.RowId``), so two recordings of the same run differ in those bytes
    (and hence in their compressed blocks) and nowhere else; and how rows are batched into
    chunks may depend on timing. So the digest is over rows: entity path, timelines,
    components and values of each row, in a sorted order (``tests/test_recording.py``).
    """
    import hashlib

    rows = []
    for ch in _chunks(path):
        rb = ch.to_record_batch()
        keep = [k for k, name in enumerate(rb.schema.names) if name != "rerun.controls.RowId"]
        rb = rb.select(keep)
        cols = [(f.name, c.to_pylist()) for f, c in zip(rb.schema, rb.columns)]
        for k in range(rb.num_rows):
            row = repr((ch.entity_path, [(name, vals[k]) for name, vals in cols if vals[k] is not None]))
            rows.append(hashlib.sha256(row.encode()).hexdigest())
    return hashlib.sha256("".join(sorted(rows)).encode()).hexdigest()


def view_time_ranges(path: str | Path) -> list[list[dict]]:
    """The visible time ranges each view of the stored blueprint declares (overrides excluded):
    one list per view of ``{"timeline", "range": {"start", "end"}}`` (None = unbounded)."""
    r = rrc.RrdReader(str(path))
    out = []
    for bp in r.blueprints():
        for ch in r.stream(store=bp):
            if ch.entity_path.startswith("/view/") and ch.entity_path.endswith("/VisibleTimeRanges"):
                col = _column(ch.to_record_batch(), "VisibleTimeRanges:ranges")
                out += [x for x in col.to_pylist()] if col is not None else []
    return out


def views(path: str | Path) -> list[dict]:
    """Every view of the stored blueprint: ``{"class", "name", "origin", "contents", "properties"}``
    (e.g. Spatial3D, "world", "/world"). ``contents`` is the view's entity query (a list of rules,
    ``$origin`` as stored); ``properties`` maps each view property archetype to its fields, e.g.
    ``{"EyeControls3D": {"position": [x, y, z], ...}, "ScalarAxis": {"range": [lo, hi]}}``
    (a single-valued field as its value, as the blueprint stores it last)."""
    r = rrc.RrdReader(str(path))
    found: dict[str, dict] = {}
    for bp in r.blueprints():
        for ch in r.stream(store=bp):
            parts = ch.entity_path.split("/")  # "", "view", id[, archetype]
            if len(parts) < 3 or parts[1] != "view" or len(parts) > 4:
                continue
            view = found.setdefault(parts[2], {"properties": {}, "contents": ["$origin/**"]})
            for field, value in _last_row(ch.to_record_batch()).items():
                archetype, _, name = field.partition(":")
                if archetype == "ViewBlueprint":
                    view[{"class_identifier": "class", "display_name": "name", "space_origin": "origin"}.get(
                        name, name)] = _first(value)
                elif archetype == "ViewContents" and name == "query":
                    view["contents"] = list(value)
                elif len(parts) == 4:
                    view["properties"].setdefault(archetype, {})[name] = _first(value) if _mono(value) else value
    return [{"class": v.get("class"), "name": v.get("name"), "origin": v.get("origin"), "contents": v["contents"],
             "properties": v["properties"]} for v in found.values() if "class" in v]


def _last_row(rb) -> dict:
    """The non-null components of a record batch's last row (``rerun.*``, timeline columns left out)."""
    out = {}
    for name, col in zip(rb.schema.names, rb.columns):
        if ":" not in name or rb.num_rows == 0:
            continue
        value = col[rb.num_rows - 1].as_py()
        if value is not None:
            out[name] = value
    return out


def _mono(value) -> bool:
    return isinstance(value, list) and len(value) == 1


def view_entities(path: str | Path, view: dict) -> set[str]:
    """The entities of the recording that ``view``'s contents select (its origin's subtree by default):
    rules ``PATH``, ``PATH/**`` (the path and everything under it) and ``- RULE`` (excluded), with
    ``$origin`` replaced; an entity is in the view when an inclusion rule matches it and no exclusion
    does."""
    def norm(rule: str) -> str:
        rule = rule.replace("$origin", view["origin"].rstrip("/"))
        return rule if rule.startswith("/") else "/" + rule

    def matches(rule: str, entity: str) -> bool:
        if rule.endswith("/**"):
            base = rule[:-3]
            return entity == base or entity.startswith(base + "/")
        return entity == rule

    rules = [(r.strip().startswith("-"), norm(r.strip().lstrip("+-").strip())) for r in view["contents"]]
    return {e for e in entity_paths(path)
            if any(matches(r, e) for exc, r in rules if not exc) and not any(matches(r, e) for exc, r in rules if exc)}


def static_components(path: str | Path, entity: str) -> dict:
    """The static components an entity holds (last value of each), e.g. ``{"SeriesLines:names": ["HPL"]}``."""
    entity = entity if entity.startswith("/") else "/" + entity
    out: dict = {}
    for ch in _chunks(path):
        if ch.entity_path == entity and ch.is_static:
            out.update(_last_row(ch.to_record_batch()))
    return out


def scalar_entities(path: str | Path) -> set[str]:
    """The entities that hold a time series (``Scalars`` rows on a timeline)."""
    return {ch.entity_path for ch in _chunks(path)
            if not ch.is_static and "Scalars:scalars" in ch.to_record_batch().schema.names}


def rgba(packed: int) -> tuple[int, int, int, int]:
    """A stored colour (``0xRRGGBBAA``) as ``(r, g, b, a)``."""
    packed = int(packed)
    return (packed >> 24) & 255, (packed >> 16) & 255, (packed >> 8) & 255, packed & 255


def _first(x):
    return x[0] if isinstance(x, list) and x else x


def component_rows(path: str | Path, entity: str, column: str) -> tuple[np.ndarray, list]:
    """``(t_s, values)`` of one component column (e.g. ``"Ellipsoids3D:half_sizes"``) of an
    entity's temporal rows, sorted by time: each value is that row's list of instances."""
    entity = entity if entity.startswith("/") else "/" + entity
    rows = []
    for ch in _chunks(path):
        if ch.entity_path != entity or ch.is_static:
            continue
        rb = ch.to_record_batch()
        t, c = _column(rb, "sim_time"), _column(rb, column)
        if t is None or c is None:
            continue
        rows += list(zip((t.cast("int64").to_numpy() * 1e-9).tolist(), c.to_pylist()))
    rows.sort(key=lambda r: r[0])
    return np.array([r[0] for r in rows]), [r[1] for r in rows]


def has_blueprint(path: str | Path) -> bool:
    return bool(rrc.RrdReader(str(path)).blueprints())


def _column(rb, name):
    names = rb.schema.names
    return rb.column(names.index(name)) if name in names else None


def scalar_series(path: str | Path, entity: str) -> tuple[np.ndarray, np.ndarray]:
    """``(t_s, values)`` of a ``Scalars`` series, sorted by time."""
    entity = entity if entity.startswith("/") else "/" + entity
    ts, vs = [], []
    for ch in _chunks(path):
        if ch.entity_path != entity or ch.is_static:
            continue
        rb = ch.to_record_batch()
        t, v = _column(rb, "sim_time"), _column(rb, "Scalars:scalars")
        if t is None or v is None:
            continue
        ts.append(t.cast("int64").to_numpy() * 1e-9)
        vs.append(np.array([x[0] if x is not None and len(x) else np.nan for x in v.to_pylist()], float))
    if not ts:
        raise KeyError(f"{path}: no scalar series at {entity}")
    t, v = np.concatenate(ts), np.concatenate(vs)
    order = np.argsort(t, kind="stable")
    return t[order], v[order]


def text_log(path: str | Path, entity: str = "/alerts") -> list[tuple[float, str, str]]:
    """``[(t_s, level, text)]`` of a TextLog entity, sorted by time (static entries at t = -inf)."""
    out = []
    for ch in _chunks(path):
        if ch.entity_path != entity:
            continue
        rb = ch.to_record_batch()
        t, lv, tx = _column(rb, "sim_time"), _column(rb, "TextLog:level"), _column(rb, "TextLog:text")
        times = t.cast("int64").to_numpy() * 1e-9 if t is not None else np.full(rb.num_rows, -np.inf)
        for k in range(rb.num_rows):
            level = lv[k].as_py() if lv is not None else None
            text = tx[k].as_py() if tx is not None else None
            level = level[0] if isinstance(level, list) and level else level
            text = text[0] if isinstance(text, list) and text else text
            out.append((float(times[k]), str(level), str(text)))
    return sorted(out, key=lambda e: e[0])
