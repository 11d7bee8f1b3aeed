"""The point-time conventions reference: the declared table of `schemas/time_conventions.py`,
the rule that makes it, the known drivers and how `auto` decides, as Markdown."""

from __future__ import annotations

from schemas import time_conventions as tc


def _table() -> list[str]:
    head = ["| dtype | unit | reference | field the generator writes | synth variant |",
            "|---|---|---|---|---|"]
    return head + [f"| {c.dtype} | {c.unit} | {c.reference} | `{c.field}` | `time_{c.name}` |"
                   for c in tc.CONVENTIONS]


def _excluded() -> list[str]:
    lines = ["| dtype | unit | reference | why not |", "|---|---|---|---|"]
    for d in tc.DTYPES:
        for u in tc.UNITS:
            for r in tc.REFERENCES:
                why = tc.held(d, u, r)
                if why:
                    lines.append(f"| {d} | {u} | {r} | {why} |")
    return lines


def render() -> str:
    """The page's Markdown."""
    drivers = [f"| {name} | `{c.field}` | {c.dtype} | {c.unit} | {c.reference} |"
               for name, c in tc.DRIVERS.items()]
    lo, hi = tc.SPAN_RATIO
    return "\n".join([
        "# Point-time conventions",
        "",
        "Generated from `schemas/time_conventions.py`. A LiDAR's per-point time is read by its "
        "convention: field, dtype, unit (s, ms, us, ns) and reference: `absolute` (Unix epoch), "
        "`header` (offset from the message's header stamp, which may stamp any instant of the "
        "sweep, its end included) or `first_point` (offset from the sweep's first point, which "
        "the header stamps). `header` and `first_point` decode alike (t = header + offset).",
        "",
        "## Choosing one",
        "",
        "`ingest.topics.lidar_point_time` is `auto` (default), `none` (every point takes its "
        "header stamp) or `{field, unit, reference}`, which overrides `auto`. `auto` reads the "
        f"first {tc.AUTO_SWEEPS} sweeps of the topic, takes the first field present of "
        f"{', '.join(f'`{f}`' for f in tc.TIME_FIELDS)}, and scores every unit, absolute and "
        "relative, by its evidence:",
        "",
        "- the span of the decoded point times within a sweep over the sweep period (the "
        f"median step of consecutive header stamps) must lie in [{lo}, {hi}] (inclusive); the "
        "units are a factor 1000 apart, so at most one fits;",
        "- the header stamp must lie within "
        f"{tc.HEADER_OFFSET_MAX:g} period of the decoded points (this is what tells absolute "
        "from relative);",
        "- of the relative ones, `first_point` when every sampled sweep's least offset is 0, "
        "else `header`.",
        "",
        "The decision and its numbers are the `point_time` row of `checks.parquet` (and the "
        "manifest); each sweep row names the convention (`time_field`, `time_unit`, "
        "`time_reference`). Where no convention fits, every point takes its sweep's header "
        "stamp and ingest warns once per topic. A time value never makes a point or sweep "
        "corrupt: one that cannot be read (NaN, Inf, beyond int64 ns) takes the header stamp "
        "(the `point_limits` plausibility check, fitted to the stream, may still flag it).",
        "",
        "## The declared table",
        "",
        "Every (dtype, unit, reference) the dtype can hold: the largest value written (an "
        f"epoch stamp up to {tc.MAX_EPOCH_S} s, 2100-01-01, for `absolute`; an offset up to "
        f"{tc.MAX_OFFSET_S:g} s otherwise) fits the dtype and is resolved to "
        f"{tc.RESOLUTION_NS} ns or finer (an integer's step is one unit, a float's its spacing "
        "at that value); `header` needs a signed dtype (the header stamps the sweep's end: "
        "offsets <= 0). The synthetic generator writes one variant per row "
        "(`m3gd bench variants --only time`).",
        "",
        *_table(),
        "",
        "## Not held",
        "",
        *_excluded(),
        "",
        "## Known drivers",
        "",
        "| driver | field | dtype | unit | reference |",
        "|---|---|---|---|---|",
        *drivers,
        "",
    ])
