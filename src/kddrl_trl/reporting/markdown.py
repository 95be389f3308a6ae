"""Markdown pieces every report uses, the studies' scripts included: a table and an estimate with its interval."""

from __future__ import annotations


def table(head: list[str], rows: list[list[str]]) -> list[str]:
    """The lines of a markdown table: its header, the rule and one line per row of cells."""
    return ["| " + " | ".join(head) + " |", "|" + "---|" * len(head)] + ["| " + " | ".join(r) + " |" for r in rows]


def section(heading: str, text: str, body: list[str]) -> list[str]:
    """A section's lines: its ``heading`` (with its ``#`` marks), a blank line, ``text``, a blank line, ``body``."""
    return [heading, "", text, "", *body]


def estimate(
    d: dict, fmt: str = ".1f", scale: float = 1.0, unit: str = "", alone: str = "", missing: str = "n/a"
) -> str:
    """``mean [low, high]`` of a :mod:`~kddrl_trl.reporting.stats` result (``mean``, ``ci_low``, ``ci_high``), each
    times ``scale`` in format ``fmt``, ``unit`` after the mean; ``mean`` + ``alone`` where there is no interval (one
    seed), ``missing`` where there is no mean."""
    if d.get("mean") is None:
        return missing
    mean = f"{scale * d['mean']:{fmt}}{unit}"
    if d.get("ci_low") is None:
        return mean + alone
    return f"{mean} [{scale * d['ci_low']:{fmt}}, {scale * d['ci_high']:{fmt}}]"


def percent(x: float | None, digits: int = 2) -> str:
    """``x`` as a percentage, ``"n/a"`` for None."""
    return "n/a" if x is None else f"{100 * x:.{digits}f} %"
