"""Figures of a calibration report, as standalone SVG (no plotting library).

:func:`residual_svg`: one figure per used pose, two panels, the camera image and the projector
image, each corner a dot at its observed position and an arrow along its residual (observed -
projected) magnified by a factor chosen so that the largest arrow is a tenth of the panel's width.

:func:`coverage_svg`: one device's image with the cells of the report's coverage grid that hold a
used corner shaded, and every used corner of every used pose as a dot.

Text taken from the report (pose names) is XML-escaped, so a figure is well-formed whatever the
names are.
"""

from __future__ import annotations

import math
from html import escape
from typing import Any

PANEL_WIDTH = 480.0


def _panel(
    corners: list[dict[str, Any]], key: str, residual: str, size: tuple[float, float], x0: float, title: str
) -> str:
    w, h = size
    scale = PANEL_WIDTH / w
    panel_h = h * scale
    arrows = [
        (c[key], c[residual])
        for c in corners
        if c.get(key) is not None and c.get(residual) is not None and c.get("used", True)
    ]
    largest = max((math.hypot(r[0], r[1]) for _, r in arrows), default=0.0)
    gain = (0.1 * w / largest) if largest > 0 else 1.0
    parts = [
        f'<g transform="translate({x0:.1f},30)">',
        f'<rect width="{PANEL_WIDTH:.1f}" height="{panel_h:.1f}" fill="#fafafa" stroke="#888"/>',
        f'<text x="0" y="-8" font-size="13">{escape(title)}: arrows x{gain:.0f} (largest {largest:.3f})</text>',
    ]
    for p, r in arrows:
        x, y = p[0] * scale, p[1] * scale
        x2, y2 = (p[0] + gain * r[0]) * scale, (p[1] + gain * r[1]) * scale
        parts.append(f'<circle cx="{x:.1f}" cy="{y:.1f}" r="1.8" fill="#333"/>')
        parts.append(
            f'<line x1="{x:.1f}" y1="{y:.1f}" x2="{x2:.1f}" y2="{y2:.1f}" stroke="#c0392b" stroke-width="1.2"/>'
        )
    parts.append("</g>")
    return "\n".join(parts)


def residual_svg(report: dict[str, Any], pose_name: str) -> str:
    """The SVG text of one pose's residual arrows (camera left, projector right).

    Raises ValueError when the report has no used pose of that name.
    """
    pose = next((p for p in report["poses"] if p["name"] == pose_name), None)
    if pose is None or not pose.get("used"):
        raise ValueError(f"no used pose named {pose_name!r} in the report")
    cam_w, cam_h = report["camera_size"]
    prj_w, prj_h = report["projector_size"]
    height = 60 + PANEL_WIDTH * max(cam_h / cam_w, prj_h / prj_w)
    corners = pose["corners"]
    body = [
        _panel(corners, "camera_px", "residual_camera_px", (cam_w, cam_h), 10.0, f"{pose_name} camera (px)"),
        _panel(corners, "projector_px", "residual_projector_px", (prj_w, prj_h), 30.0 + PANEL_WIDTH, "projector"),
    ]
    width = 40.0 + 2 * PANEL_WIDTH
    return (
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{width:.0f}" height="{height:.0f}" '
        f'font-family="sans-serif">\n' + "\n".join(body) + "\n</svg>\n"
    )


def coverage_cells(report: dict[str, Any], device: str) -> list[list[bool]]:
    """The report's coverage grid (``grid x grid`` cells, rows top down) of ``device`` ("camera" or
    "projector"): True where a used corner of a used pose falls (pixel centres at integers, as the
    calibration counts them; the fraction of True cells is ``report["coverage"][device]``)."""
    if device not in ("camera", "projector"):
        raise ValueError(f"device must be camera or projector, got {device!r}")
    n = int(report.get("coverage", {}).get("grid", 8))
    width, height = report[f"{device}_size"]
    cells = [[False] * n for _ in range(n)]
    for pose in report["poses"]:
        if not pose.get("used"):
            continue
        for corner in pose["corners"]:
            point = corner.get(f"{device}_px")
            if not corner.get("used") or point is None:
                continue
            i = math.floor((point[1] + 0.5) / height * n)
            j = math.floor((point[0] + 0.5) / width * n)
            if 0 <= i < n and 0 <= j < n:
                cells[i][j] = True
    return cells


def coverage_svg(report: dict[str, Any], device: str) -> str:
    """The SVG text of ``device``'s coverage: image outline (``PANEL_WIDTH`` wide), shaded grid cells
    holding a used corner, the used corners as dots, and the covered fraction in the title."""
    cells = coverage_cells(report, device)
    n = len(cells)
    width, height = report[f"{device}_size"]
    scale = PANEL_WIDTH / width
    panel_h = height * scale
    cell_w, cell_h = PANEL_WIDTH / n, panel_h / n
    covered = sum(map(sum, cells)) / (n * n)
    parts = [
        f'<svg xmlns="http://www.w3.org/2000/svg" width="{PANEL_WIDTH + 20:.0f}" height="{panel_h + 40:.0f}" '
        'font-family="sans-serif">',
        f'<text x="10" y="18" font-size="13">{device} {width}x{height}: {covered:.0%} of {n}x{n} cells hold a corner'
        "</text>",
        '<g transform="translate(10,28)">',
        f'<rect width="{PANEL_WIDTH:.1f}" height="{panel_h:.1f}" fill="#fafafa" stroke="#888"/>',
    ]
    for i, row in enumerate(cells):
        for j, filled in enumerate(row):
            if filled:
                parts.append(
                    f'<rect x="{j * cell_w:.1f}" y="{i * cell_h:.1f}" width="{cell_w:.1f}" height="{cell_h:.1f}" '
                    'fill="#cfe3f7" stroke="#9bbbe0" stroke-width="0.5"/>'
                )
    for pose in report["poses"]:
        if not pose.get("used"):
            continue
        for corner in pose["corners"]:
            point = corner.get(f"{device}_px")
            if corner.get("used") and point is not None:
                parts.append(f'<circle cx="{point[0] * scale:.1f}" cy="{point[1] * scale:.1f}" r="1.5" fill="#333"/>')
    parts += ["</g>", "</svg>", ""]
    return "\n".join(parts)
