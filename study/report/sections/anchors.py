"""The calibration's anchors: real-data effects and the two arms of this benchmark that correspond to each
(`configs/calibration/anchors.yaml`, issue 57). Loaded strictly: a row without a source, a real figure or a set,
or naming an arm that is not declared, is refused in one line naming the row and the field.

The file holds each source's before (= the base arm's configuration) and after (= the changed arm's) figures; the
reading (`study.report.sections.calibration`) takes both effects as base - changed, before - after: positive = the change helps,
the project's one sign convention.

Example::

    anchors = load_anchors("configs/calibration/anchors.yaml")
    [a.name for a in anchors.anchors if a.set == "tuning"]
"""
from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import Field, ValidationError, model_validator

from corelib.configlib import ConfigError, StrictModel

#: an arm's or an anchor's name
NAME = r"^[a-z][a-z0-9_]{0,39}$"
#: what an anchor reads of its arms besides the whole rig's figure
READS = ("arms", "side_vs_front", "metric_vs_median")
#: at most this many anchors and arms in one file (bounded input)
MAX_ROWS = 200


class Arm(StrictModel):
    """One arm: a registered method trained at the calibration recipe with its own dotted overrides."""

    method: str = Field(pattern=NAME)
    overrides: list[str] = Field(default_factory=list, max_length=32)


class Source(StrictModel):
    paper: str = Field(min_length=1, max_length=200)
    table: str = Field(min_length=1, max_length=200)
    dataset: str = Field(min_length=1, max_length=100)


class Real(StrictModel):
    before: float = Field(ge=0.0, le=100.0, allow_inf_nan=False)
    after: float = Field(ge=0.0, le=100.0, allow_inf_nan=False)

    @property
    def delta(self) -> float:
        return self.after - self.before


class AlsoReal(Source, Real):
    """A second real figure of the same effect (another dataset or paper), shown beside the row's own."""


class Anchor(StrictModel):
    """One real-data effect and its two arms here (module docstring)."""

    name: str = Field(pattern=NAME)
    effect: str = Field(min_length=1, max_length=300)
    source: Source
    real: Real
    also: list[AlsoReal] = Field(default_factory=list, max_length=8)
    base: str = Field(pattern=NAME)
    changed: str = Field(pattern=NAME)
    metric: str = Field("", max_length=80)
    read: Literal["arms", "side_vs_front", "metric_vs_median"] = "arms"
    set: Literal["tuning", "test"]
    note: str = Field("", max_length=500)

    @model_validator(mode="after")
    def _sign(self) -> "Anchor":
        if self.real.delta == 0:
            raise ValueError("real.before equals real.after: an anchor needs a real effect with a sign")
        if self.read == "arms" and self.base == self.changed:
            raise ValueError("base and changed are the same arm; only read: side_vs_front / metric_vs_median "
                             "compares one arm with itself")
        return self


class Anchors(StrictModel):
    version: Literal[1]
    metric_default: str = Field(min_length=1, max_length=80)
    arms: dict[str, Arm] = Field(max_length=MAX_ROWS)
    order: list[str] = Field(max_length=MAX_ROWS)
    anchors: list[Anchor] = Field(min_length=1, max_length=MAX_ROWS)

    def metric_of(self, a: Anchor) -> str:
        return a.metric or self.metric_default


def load_anchors(path: str | Path) -> Anchors:
    """The anchors file, validated (module docstring); ConfigError in one line naming the row and field."""
    import yaml

    from corelib.readfile import ReadRefused, read_text_inside

    p = Path(path)
    try:
        text = read_text_inside(p, p.parent, 1 << 20)
    except (ReadRefused, OSError) as exc:
        raise ConfigError(f"anchors file {p}: {exc}") from None
    try:
        raw = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise ConfigError(f"{p}: not YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(raw, dict):
        raise ConfigError(f"{p}: must be a mapping with version, metric_default, arms, order, anchors")
    rows = raw.get("anchors")
    if isinstance(rows, list):  # each row on its own first, so the message names it
        for i, row in enumerate(rows[:MAX_ROWS]):
            name = row.get("name", f"#{i}") if isinstance(row, dict) else f"#{i}"
            try:
                Anchor.model_validate(row)
            except ValidationError as exc:
                err = exc.errors()[0]
                msg = str(err["msg"]).removeprefix("Value error, ")
                where = ".".join(str(x) for x in err["loc"])
                raise ConfigError(f"{p}: anchor {name!r}: " + (f"{where}: {msg}" if where else msg)) from None
    try:
        out = Anchors.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        raise ConfigError(f"{p}: {'.'.join(str(x) for x in err['loc'])}: {err['msg']}") from None
    names = [a.name for a in out.anchors]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise ConfigError(f"{p}: anchor {dup[0]!r} is named twice")
    for a in out.anchors:
        for field in ("base", "changed"):
            if getattr(a, field) not in out.arms:
                raise ConfigError(f"{p}: anchor {a.name!r}: {field}: arm {getattr(a, field)!r} is not declared under "
                                  f"arms ({', '.join(out.arms)})")
    if sorted(out.order) != sorted(out.arms):
        raise ConfigError(f"{p}: order must list every arm once: {', '.join(out.arms)}")
    return out
