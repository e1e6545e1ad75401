"""Base for every configuration model: strict, immutable, with clear errors.

Section models live beside the code they configure (``flight/settings.py``,
``sensors/gnss/settings.py`` ...); ``config.py`` composes them and loads TOML.
Every model derives from :class:`StrictModel`, so an unknown key is an error
that names the key path, and nothing can be changed after validation.
"""

from __future__ import annotations

from pathlib import Path

from pydantic import BaseModel, ConfigDict, ValidationError


class StrictModel(BaseModel):
    """Unknown keys are errors; instances are frozen; no silent type coercion from str."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=False, validate_default=True)


class ConfigError(ValueError):
    """A configuration file failed to load or validate.

    The message lists every problem as ``file: key.path: what was expected``.
    """

    def __init__(self, source: str | Path, problems: list[str]) -> None:
        self.source = str(source)
        self.problems = list(problems)
        lines = "\n".join(f"  {self.source}: {p}" for p in self.problems)
        super().__init__(f"{len(self.problems)} problem(s) in {self.source}:\n{lines}")


def format_validation_error(err: ValidationError) -> list[str]:
    """Turn a pydantic error into ``key.path: message (got value)`` lines."""
    out = []
    for e in err.errors():
        loc = ".".join(str(p) for p in e["loc"]) or "<top level>"
        msg = e["msg"]
        if e["type"] == "extra_forbidden":
            msg = "unknown key (check the spelling; see README 'Configuration')"
        got = e.get("input")
        got_s = "" if e["type"] in ("missing", "extra_forbidden") else f" (got {got!r})"
        if len(got_s) > 120:
            got_s = got_s[:117] + "...)"
        out.append(f"{loc}: {msg}{got_s}")
    return out
