"""Reading the dashboard's pages: the figures' data embedded in a page, and what each page that lists
captures must show."""

from __future__ import annotations

import json
import re


def figure_data(html: str, name: str) -> dict:
    match = re.search(rf'<script type="application/json" id="fig-{name}-data">(.*?)</script>', html, re.S)
    assert match, f"figure {name} not on the page"
    return json.loads(match.group(1))


def capture_listing_pages(rig_id: int, reference: int, obj: int) -> dict[str, list[str]]:
    """Every page that lists a user's captures, with what it must show of the two uploads."""
    table = [f"<td>#{reference}</td>", f"<td>#{obj}</td>", "plane-r.zip", "block-o.zip"]
    return {
        "/captures/": table,
        f"/rigs/{rig_id}/captures/": table,
        f"/rigs/{rig_id}/": [f"#{reference} reference", f"#{obj} object"],
        f"/measurements/new/?rig={rig_id}": [f"#{reference} reference (plane-r.zip)", f"#{obj} object (block-o.zip)"],
        f"/calibrations/new/?rig={rig_id}": [f"#{reference} reference (plane-r.zip)", f"#{obj} object (block-o.zip)"],
        f"/characterizations/new/?rig={rig_id}": [f"#{reference} reference (plane-r.zip)"],
    }
