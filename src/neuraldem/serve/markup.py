"""HTML pieces every page's numbers use: exact values in data attributes (what the browser tests read back),
the GP cell with its interval, the field model's cell, and the list of notes."""

from __future__ import annotations

import html


def exact(v: float) -> str:
    """A value as its shortest exact decimal (read back to the same float)."""
    return repr(float(v))


def gp_cell(mean: float, low: float, high: float, text: str) -> str:
    return f'<td class="gp" data-mean="{exact(mean)}" data-low="{exact(low)}" data-high="{exact(high)}">{text}</td>'


def field_cell(value: float | None, text: str, pending: str) -> str:
    """The field model's value, or (None) its state while it computes."""
    if value is None:
        return f'<td class="field pending">{html.escape(pending)}</td>'
    return f'<td class="field" data-value="{exact(value)}">{text}</td>'


def notes_html(notes: list[str], element_id: str) -> str:
    """Warnings and clamping notes marked 'warn', the rest 'info'."""
    items = "".join(f'<li class="{"warn" if n.startswith("warning") or "clamped" in n else "info"}">'
                    f"{html.escape(n)}</li>" for n in notes)
    return f'<ul id="{element_id}" class="nd-notes">{items}</ul>'


# the explorer's style, shared by every page
CSS = """
.nd-numbers {border-collapse: collapse; font-size: 12px;}
.nd-numbers td, .nd-numbers th {border-bottom: 1px solid #ddd; padding: 2px 6px; text-align: left;}
.nd-numbers td + td, .nd-numbers th + th {white-space: nowrap;}
.nd-numbers td.pending {color: #888; font-style: italic;}
.nd-notes {margin: 0; padding-left: 18px; font-size: 12px;}
.nd-notes li.warn {color: #b15c00;}
.nd-notes li.info {color: #555;}
"""
