"""The OpenAPI schema's shared parts: the error body, the error responses of every operation, and
request examples (drf-spectacular post-processing hook, so the views stay as they are).

Every operation under ``/api/`` documents ``{"error": "..."}`` answers: 400 (refused input; body
endpoints and ones with query or path values), 401 (no or bad credentials), 404 (an id that is not
among yours), 413 (body too large), 429 (rate limit, with ``Retry-After``); and the operations of
:data:`CONFLICT_OPERATIONS`, whose services raise :class:`metrology.errors.Conflict`, document 409.
"""

from __future__ import annotations

from typing import Any

ERROR_SCHEMA: dict[str, Any] = {
    "type": "object",
    "description": 'Every error: {"error": "<what is wrong and what to do>"}; validation errors add "fields".',
    "properties": {
        "error": {"type": "string", "example": 'scene.name is required, e.g. {"name": "plane", ...}'},
        "fields": {
            "type": "object",
            "additionalProperties": True,
            "description": "Per-field messages of a refused form (validation errors only)",
        },
    },
    "required": ["error"],
}

ERROR_RESPONSES: dict[str, str] = {
    "400": "Refused input: the message names the field and the problem; nothing was stored.",
    "401": "No credentials, or an unknown token (send 'Authorization: Token <key>').",
    "404": "No such object among yours (others' objects are not shown).",
    "413": "Request body larger than the limit (DATA_UPLOAD_MAX_MEMORY_SIZE, GCPS_MAX_UPLOAD_BYTES for uploads).",
    "429": "Rate limit reached (GCPS_THROTTLE_*): wait Retry-After seconds.",
}

_AGENT_GONE = "the agent session is unknown or was disconnected (register again)"

#: Operations answering 409 (their services raise :class:`metrology.errors.Conflict`): operation id ->
#: when. Documented by :func:`add_errors_and_examples`; ``tests/app/test_schema_conflicts.py`` checks
#: that each one does answer 409 and that every 409 the API answers is documented here.
CONFLICT_OPERATIONS: dict[str, str] = {
    "rig_agent_register": "Another capture agent of the rig is connected: stop it first.",
    "rig_agent_heartbeat": f"The state refuses it: {_AGENT_GONE}.",
    "rig_agent_disconnect": f"The state refuses it: {_AGENT_GONE}.",
    "rig_agent_take": f"The state refuses it: {_AGENT_GONE}.",
    "rig_projector_show": f"The state refuses it: {_AGENT_GONE}.",
    "acquisitions_progress": (
        f"The state refuses it: {_AGENT_GONE}, or the acquisition is not running or not taken by this agent."
    ),
    "acquisitions_fail": (
        f"The state refuses it: {_AGENT_GONE}, or the acquisition is not running or not taken by this agent."
    ),
    "acquisitions_upload": (
        f"The state refuses it: {_AGENT_GONE}, or the acquisition is not running or not taken by this agent."
    ),
    "measurements_acceptance": "The measurement is not done (queued, running or failed): no stored result to fit.",
}

PAPER_RIG = {"L_mm": 1022.0, "d_mm": 352.0, "alpha_rad": 0.332, "fw_mm": 500.0, "nlp": 128}

#: Request examples per operation id: name -> (summary, value).
REQUEST_EXAMPLES: dict[str, dict[str, tuple[str, Any]]] = {
    "rigs_create": {
        "paper": (
            "The paper's rig at 640x480 px; further keys (lens) are kept in extra",
            {"name": "bench 1", **PAPER_RIG, "width_px": 640, "height_px": 480, "lens": "25 mm"},
        ),
    },
    "rig_captures_simulate": {
        "object": (
            "A sphere, realistic 8-bit camera (the default preset)",
            {"role": "object", "scene": {"name": "sphere", "radius_mm": 50.0}, "options": {"seed": 1}},
        ),
        "reference": (
            "The reference plane, exact 16-bit rendering",
            {"role": "reference", "scene": {"name": "reference"}, "preset": "noise-free"},
        ),
        "stage": (
            "A stage capture at Z_in = 4 mm, repeat 0, in session 1",
            {"role": "stage", "scene": {"name": "stage"}, "z_in_mm": 4.0, "repeat": 0, "session": 1},
        ),
        "master": (
            "The master block, top 40 mm above R",
            {"role": "master", "scene": {"name": "block", "top_mm": 40.0}},
        ),
    },
    "rig_sessions_create": {"stage": ("A session for a stage series", {"name": "stage 0-80 mm", "notes": ""})},
    "measurements_create": {
        "pair": ("Object capture 2 against reference capture 1", {"rig": 1, "reference": 1, "object": 2})
    },
    "calibrations_create": {
        "paper-start": (
            "From the paper's rough start, least squares, result not applied",
            {
                "rig": 1,
                "reference": 1,
                "master": 3,
                "master_height_mm": 40.0,
                "method": "lsq",
                "initial": {"L_mm": 1080.0, "alpha_rad": 0.4871},
                "apply": False,
            },
        ),
    },
    "procam_calibrations_create": {
        "eight-poses": (
            "Eight board captures of rig 1, a board of 10 x 8 squares of 25 mm (9x7 inner corners), result applied",
            {"rig": 1, "poses": [11, 12, 13, 14, 15, 16, 17, 18], "board": "chessboard:9x7:25", "apply": True},
        ),
        "options": (
            "Five poses, k3 held at 0, corner windows of 12 px",
            {
                "rig": 1,
                "poses": [21, 22, 23, 24, 25],
                "board": "chessboard:9x6:20",
                "options": {"fix_k3": True, "window": 12, "min_decoded": 0.3},
            },
        ),
    },
    "characterizations_create": {
        "session": ("The stage captures of session 4", {"rig": 1, "reference": 1, "session": 4}),
        "series": (
            "Explicit positions and their repeats",
            {
                "rig": 1,
                "reference": 1,
                "series": [{"z_in_mm": 0.0, "captures": [5, 6]}, {"z_in_mm": 4.0, "captures": [7, 8]}],
            },
        ),
    },
}


def _error_response(code: str, description: str) -> dict[str, Any]:
    response: dict[str, Any] = {
        "description": description,
        "content": {"application/json": {"schema": {"$ref": "#/components/schemas/Error"}}},
    }
    if code == "429":
        response["headers"] = {
            "Retry-After": {"schema": {"type": "integer"}, "description": "Seconds to wait before trying again"}
        }
    return response


def add_errors_and_examples(result: dict[str, Any], generator: Any, request: Any, public: bool) -> dict[str, Any]:
    """drf-spectacular post-processing hook: error responses and request examples of every API operation."""
    result.setdefault("components", {}).setdefault("schemas", {})["Error"] = ERROR_SCHEMA
    for path, operations in result.get("paths", {}).items():
        if not path.startswith("/api/") or path.startswith(("/api/schema", "/api/docs")):
            continue
        for method, operation in operations.items():
            if not isinstance(operation, dict) or "responses" not in operation:
                continue
            codes = ["401", "429"]
            if "requestBody" in operation or operation.get("parameters"):
                codes.append("400")
            if "{" in path:
                codes.append("404")
            if method in ("post", "put", "patch"):
                codes.append("413")
            for code in sorted(codes):
                operation["responses"].setdefault(code, _error_response(code, ERROR_RESPONSES[code]))
            conflict = CONFLICT_OPERATIONS.get(operation.get("operationId", ""))
            if conflict is not None:
                operation["responses"].setdefault("409", _error_response("409", conflict))
            examples = REQUEST_EXAMPLES.get(operation.get("operationId", ""))
            body = operation.get("requestBody", {}).get("content", {}).get("application/json")
            if examples and body is not None:
                body["examples"] = {
                    name: {"summary": summary, "value": value} for name, (summary, value) in examples.items()
                }
    return result
